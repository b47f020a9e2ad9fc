"""The registry (registry.py): names map to the contract's classes, imported only when asked
for and checked when loaded; a name, a library or a class that is not there is an error that
says so; what a config alone tells (sections, driver chips, lost steps) needs no backend."""

from __future__ import annotations

import pytest

from motorctl.daemon.config import parse_config
from motorctl.hal import registry
from motorctl.hal.backends.gpiod.backend import GpiodBackend
from motorctl.hal.backends.gpiod.config import GpiodDeclaration
from motorctl.hal.backends.mock.backend import MockBackend
from motorctl.hal.backends.mock.config import MockConfig, MockDeclaration
from motorctl.hal.backends.mock.world import mock_axis, world_of
from motorctl.hal.contract import Backend, Layer, ProbeReport
from motorctl.hal.interfaces import Clock, HalError, Hardware, VirtualClock
from motorctl.hal.layers.dspin.config import DspinDeclaration
from motorctl.hal.layers.dspin.layer import DspinLayer
from motorctl.hal.layers.tmc.config import TmcDeclaration
from motorctl.hal.layers.tmc.layer import TmcLayer
from motorctl.hal.layers.tmc.settings import TmcSettings, TmcSpec
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import SpiFactory

#: every class of the tables, named here so that the type checker checks each is concrete
IMPLEMENTATIONS: dict[str, type[Backend] | type[Layer]] = {
    "mock": MockBackend,
    "gpiod": GpiodBackend,
    "tmc": TmcLayer,
    "dspin": DspinLayer,
}
DECLARATIONS = {
    "mock": MockDeclaration(),
    "gpiod": GpiodDeclaration(),
    "tmc": TmcDeclaration(),
    "dspin": DspinDeclaration(),
}


def test_every_name_maps_to_the_contracts_classes() -> None:
    assert set(registry.BACKENDS) == {"mock", "gpiod"} and set(registry.LAYERS) == {"tmc", "dspin"}
    for name in registry.BACKENDS:
        found = registry.backend(name)
        assert type(found) is IMPLEMENTATIONS[name] and found.name == name
        assert type(registry.backend_declaration(name)) is type(DECLARATIONS[name])
    for name, declaration in registry.layer_declarations().items():
        assert type(declaration) is type(DECLARATIONS[name])
        found_layer = registry.layer(name)
        assert type(found_layer) is IMPLEMENTATIONS[name] and found_layer.name == name
    assert [name for name, _ in registry.config_sections()] == [
        "hal",
        "mock",
        "gpiod",
        "tmc",
        "dspin",
    ]


def test_an_unknown_backend_names_the_ones_there_are() -> None:
    with pytest.raises(HalError, match=r"unknown hardware backend 'gpio'; available: gpiod, mock"):
        registry.backend("gpio")


def test_a_backend_whose_library_is_missing_says_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    entry = registry.Entry(registry.BACKENDS["mock"].declaration, "no_such_lib:B", "apt install x")
    monkeypatch.setitem(registry.BACKENDS, "fake", entry)
    with pytest.raises(HalError, match=r"backend 'fake' failed to load: .*no_such_lib.*apt inst"):
        registry.open_hardware("fake", HardwareSpec(()), VirtualClock())


@pytest.mark.parametrize(
    ("implementation", "says"),
    [
        ("motorctl.hal.backends.mock.config:MockDeclaration", "is no Backend"),
        ("motorctl.hal.backends.mock.backend:build", "is not a class"),
        ("motorctl.hal.backends.mock.backend:Nothing", "is not a class"),
    ],
)
def test_what_the_table_names_is_checked_when_loaded(
    monkeypatch: pytest.MonkeyPatch, implementation: str, says: str
) -> None:
    entry = registry.Entry(registry.BACKENDS["mock"].declaration, implementation, "")
    monkeypatch.setitem(registry.BACKENDS, "odd", entry)
    with pytest.raises(HalError, match=says):
        registry.backend("odd")


class BrokenLayer(Layer):
    """A layer whose parts cannot be opened."""

    name = "broken"

    def attach(self, hw: Hardware, spec: HardwareSpec, clock: Clock) -> None:
        raise HalError("broken: nothing there")

    def probe(
        self,
        spec: HardwareSpec,
        clock: Clock,
        report: ProbeReport,
        spi_factory: SpiFactory | None = None,
    ) -> None:
        raise HalError("nothing there")


def test_a_layer_that_fails_closes_the_hardware_and_is_a_problem_of_the_probe(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    closed: list[Hardware] = []
    real_build = MockBackend.build

    def build(self: MockBackend, spec: HardwareSpec, clock: Clock) -> Hardware:
        hw = real_build(self, spec, clock)
        hw.closers.append(lambda: closed.append(hw))
        return hw

    monkeypatch.setattr(MockBackend, "build", build)
    entry = registry.Entry(registry.LAYERS["tmc"].declaration, f"{__name__}:BrokenLayer", "")
    monkeypatch.setitem(registry.LAYERS, "tmc", entry)
    spec = HardwareSpec((mock_axis(driver=TmcSpec("/dev/spidev0.0", TmcSettings())),))
    with pytest.raises(HalError, match="broken: nothing there"):
        registry.open_hardware("mock", spec, VirtualClock())
    assert len(closed) == 1
    report = registry.probe_hardware("mock", spec, VirtualClock())
    assert [p.text for p in report.problems] == ["tmc: nothing there"]


def test_what_a_config_alone_tells_needs_no_backend() -> None:
    config = parse_config(
        '[[motors]]\nname = "a"\n[motors.tmc]\n[[motors]]\nname = "b"\n'
        "[mock]\nlose_steps = true\nwires = []\n",
        "t.toml",
    )
    first, second = (registry.driver_spec(m) for m in config.motors)
    assert isinstance(first, TmcSpec) and first.spi == "/dev/spidev0.0" and second is None
    world = HardwareSpec((), sections={MockConfig: config.section(MockConfig)})
    assert registry.motors_lose_steps("mock", world)
    assert not registry.motors_lose_steps("mock", HardwareSpec(()))  # no [mock]: no rotors
    assert registry.motors_lose_steps("gpiod", world)  # real rotors: the contract's default
    assert registry.motors_lose_steps("unknown", world)


def test_open_hardware_and_step_io_by_name() -> None:
    spec = HardwareSpec((mock_axis(),))
    hw = registry.open_hardware("mock", spec, VirtualClock())
    io = registry.open_step_io("mock", spec, hw.clock, hw)
    try:
        assert io.compiled is not None  # the contract's open_step_io asked compiled_lines
        world_of(hw).force_endstop(0, "min", True)
        assert io.inputs.level(0)  # the same world in-process
    finally:
        io.close()
        hw.close()


def test_a_layer_that_does_not_load_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    entry = registry.Entry(registry.LAYERS["tmc"].declaration, "no_such_layer:L", "reinstall")
    monkeypatch.setitem(registry.LAYERS, "tmc", entry)
    spec = HardwareSpec((mock_axis(driver=TmcSpec("/dev/spidev0.0", TmcSettings())),))
    with pytest.raises(HalError, match=r"layer 'tmc' failed to load: .*no_such_layer.*reinstall"):
        registry.open_hardware("mock", spec, VirtualClock())
    (problem,) = registry.probe_hardware("mock", spec, VirtualClock()).problems
    assert problem.text.startswith("tmc: layer 'tmc' failed to load")
