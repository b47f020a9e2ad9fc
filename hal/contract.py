"""The backend contract: what a hardware backend and a layer are, as classes that the registry
builds by name and the type checker checks (python-can's ``BusABC`` and its interface table).

A backend (``[hal] backend = "mock"`` or ``"gpiod"``) builds the machine; a layer (the TMC
driver chips over SPI) works with any backend and attaches to what it built. Each is two
classes in two modules of its package, because a config is read, checked and documented on
machines that lack its hardware library:

- its declaration (:class:`BackendDeclaration`, :class:`LayerDeclaration`) in its
  ``config.py``, imported whenever a config is read, importing no hardware library: its
  config sections and what a config alone tells;
- its implementation (:class:`Backend`, :class:`Layer`) in its ``backend.py`` or
  ``layer.py``, imported only when the config uses it; it may import its hardware library.

``registry.py`` maps each name to both classes, imports them when asked, checks that they
are what the table says and is the only code that names them (tests/test_imports.py). As in
python-can, what only some can do is a method here with a neutral default:
:meth:`Backend.probe` (default: nothing to open), :meth:`Backend.compiled_lines` (the
capability "lines a compiled core may drive"; default: none, saying why),
:meth:`BackendDeclaration.motors_lose_steps` (default: real rotors may) and
:meth:`LayerDeclaration.driver_spec` (default: no driver chip). A public method that
completes what a hook gives is here too: :meth:`Backend.open_step_io`.

And what ``motorctld --probe`` collects: a :class:`ProbeReport`, its problems as data
(:class:`Problem`, each of a :class:`ProblemKind`), never found by matching words.

The declarations and implementations hold no state of their own (what they build does):
any thread may use them. A ProbeReport belongs to the thread that probes.
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol, TypeVar

from motorctl.hal.compiled_lines import NO_COMPILED_LINES, CompiledLines
from motorctl.hal.interfaces import Clock, Hardware, StepIO
from motorctl.hal.spec import DriverSpec, HardwareSpec
from motorctl.schema import Extension

if TYPE_CHECKING:  # hal/spi.py imports py-spidev only when a node opens; no cycle either way
    from motorctl.hal.spi import SpiFactory

T = TypeVar("T")


class MotorEntry(Protocol):
    """What a declaration reads of a loaded ``[[motors]]`` entry (the daemon's MotorConfig):
    its name, its direction, its steps per revolution (0: a linear axis) and its sections
    (``[motors.<name>]``)."""

    @property
    def name(self) -> str: ...

    @property
    def invert_dir(self) -> bool: ...

    @property
    def steps_per_rev(self) -> int: ...

    def section(self, cls: type[T]) -> T: ...


#: a loaded [[motors]] entry's driver chip, as the layers read it (``registry.driver_spec``)
DriverLookup = Callable[[MotorEntry], DriverSpec | None]


class ChipTable(Mapping[str, T]):
    """A layer's chips by the names its config takes: the names written here, in the
    declaration, the chips themselves (register tables, ramp generators) imported by ``load``
    when one is first asked for, so that a config without such a chip imports none of them
    (a start on the default config: tests/daemon/start/test_launch_startup.py).

    ``load`` returns every chip by name; a table that names other chips than it loads is a
    programming error, raised (RuntimeError) at the first chip asked for, never a chip
    silently missing from a config's choices."""

    def __init__(self, names: tuple[str, ...], load: Callable[[], Mapping[str, T]]) -> None:
        self._names = names
        self._load = load

    def __getitem__(self, name: str) -> T:
        if name not in self._names:
            raise KeyError(name)
        chips = self._load()
        if tuple(chips) != self._names:
            raise RuntimeError(f"the chips are {tuple(chips)}, the table names {self._names}")
        return chips[name]

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


class ProblemKind(enum.StrEnum):
    """What kind of problem ``--probe`` found."""

    CONFIG = "config"  # the config asks for what cannot be (a line written twice)
    DEVICE = "device"  # a device, line or library is missing, busy, refused or fails
    MISMATCH = "mismatch"  # something answers, but not as configured (another chip)


@dataclass(frozen=True)
class Problem:
    """One problem ``--probe`` found: what the user reads, and its kind."""

    text: str
    kind: ProblemKind = ProblemKind.DEVICE

    def __str__(self) -> str:
        return self.text


@dataclass
class ProbeReport:
    """What ``motorctld --probe`` prints: sections of lines (each backend and layer adds its
    own), then its problems; any problem fails the probe (exit status 1)."""

    sections: list[tuple[str, list[str]]] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    #: what the step IO offers a compiled step core (StepIO.compiled_text), when the probe
    #: opened it
    compiled_lines: str | None = None

    def add(self, title: str, lines: list[str]) -> None:
        self.sections.append((title, lines))

    def problem(self, text: str, kind: ProblemKind = ProblemKind.DEVICE) -> None:
        self.problems.append(Problem(text, kind))

    def text(self) -> str:
        out: list[str] = []
        for title, lines in self.sections:
            out.append(f"{title}:")
            out += [f"  {line}" for line in lines]
        for p in self.problems:
            out.append(f"PROBLEM: {p.text}")
        return "\n".join(out) + "\n"


class BackendDeclaration(ABC):
    """A hardware backend's declaration, in its ``config.py``: imports no hardware library."""

    @abstractmethod
    def sections(self, drivers: DriverLookup) -> tuple[Extension, ...]:
        """Its config sections (``[<name>]``, ``[motors.<name>]``, ``[pins.<name>]``), as
        ``motorctl.schema`` Extensions. ``drivers`` gives a loaded ``[[motors]]`` entry's
        driver chip as the layers read it, for a rule that depends on it (a motor whose chip
        runs its own ramp has no STEP/DIR lines)."""

    def motors_lose_steps(self, spec: HardwareSpec) -> bool:
        """Whether a late step may cost its motors steps, known without building it (as
        the Hardware it builds says, ``Hardware.motors_lose_steps``). Default: True, the
        motors have rotors."""
        return True


class Backend(ABC):
    """A hardware backend, in its ``backend.py``: builds the daemon's part of the machine
    and, in the executor's thread or process, the step executor's lines."""

    #: its name in the registry and in ``[hal] backend`` (messages)
    name: ClassVar[str]

    @abstractmethod
    def build(self, spec: HardwareSpec, clock: Clock) -> Hardware:
        """What the daemon's process owns: drivers, pins, the DC bridge. A failure to open
        is a HalError naming the device and the fix; nothing stays open then."""

    @abstractmethod
    def build_step_io(self, spec: HardwareSpec, clock: Clock, parent: Hardware | None) -> StepIO:
        """The hook of :meth:`open_step_io`: the STEP/DIR outputs and end-stop inputs of the
        axes ``spec.stepped()`` names (the StepIO's motor j is axis ``stepped()[j]``).
        ``parent``: the daemon's Hardware when the executor runs in its process (a backend
        may share state with it, as the mock its timeline), None in the executor's own
        process, which has only the picklable ``spec``."""

    def compiled_lines(self, io: StepIO) -> CompiledLines | str:
        """The optional capability "lines a compiled core may drive": ``io``'s lines as a
        compiled step core drives them (hal/compiled_lines.py), or why there are none.
        Default: none."""
        return NO_COMPILED_LINES

    def open_step_io(
        self, spec: HardwareSpec, clock: Clock, parent: Hardware | None = None
    ) -> StepIO:
        """The step executor's lines (:meth:`build_step_io`) with what they offer a compiled
        core (:meth:`compiled_lines`) in ``StepIO.compiled``, or why not in
        ``StepIO.compiled_missing``."""
        io = self.build_step_io(spec, clock, parent)
        try:
            io.set_compiled(self.compiled_lines(io))
        except BaseException:
            io.close()
            raise
        return io

    def simulated_spi(self, spec: HardwareSpec, clock: Clock) -> SpiFactory | None:
        """The SPI devices it simulates (the mock's dSPIN chains) as py-spidev's API, for the
        layers' ``--probe`` (:meth:`Layer.probe`); what it builds has them as
        ``Hardware.spi_factory``. Default: None, the kernel's devices."""
        return None

    def probe(self, spec: HardwareSpec, clock: Clock, report: ProbeReport) -> None:
        """``motorctld --probe``: open what the config names without moving anything and add
        what was found to ``report``, problems included (a HalError that escapes is added
        by the registry). Default, for a backend that opens no hardware: it says so, and
        what its step IO offers a compiled core."""
        report.add(f"backend {self.name}", ["nothing to probe: no hardware is opened"])
        io = self.open_step_io(spec, clock)
        try:
            report.compiled_lines = io.compiled_text()
        finally:
            io.close()


class LayerDeclaration(ABC):
    """A layer's declaration, in its ``config.py``: imports no hardware library."""

    @abstractmethod
    def sections(self) -> tuple[Extension, ...]:
        """Its config sections, as ``motorctl.schema`` Extensions."""

    @abstractmethod
    def applies(self, spec: HardwareSpec) -> bool:
        """Whether ``spec`` uses the layer: then the registry attaches it to the hardware
        (and probes it)."""

    def driver_spec(self, motor: MotorEntry) -> DriverSpec | None:
        """The driver chip a loaded ``[[motors]]`` entry's sections give it, None when none
        of this layer's. Default: none."""
        return None


class Layer(ABC):
    """A layer, in its ``layer.py``: attaches its parts to any backend's hardware."""

    #: its name in the registry (messages)
    name: ClassVar[str]

    @abstractmethod
    def attach(self, hw: Hardware, spec: HardwareSpec, clock: Clock) -> None:
        """Open its parts, put them into ``hw`` (a motor's driver in place of the
        backend's) and close them with it (``hw.closers``). On an error, a HalError naming
        the device and the fix, and nothing of it stays open."""

    @abstractmethod
    def probe(
        self,
        spec: HardwareSpec,
        clock: Clock,
        report: ProbeReport,
        spi_factory: SpiFactory | None = None,
    ) -> None:
        """As :meth:`Backend.probe`, for its own parts: reads only, moves nothing.
        ``spi_factory``: the SPI devices the backend simulates
        (:meth:`Backend.simulated_spi`), None: the kernel's."""
