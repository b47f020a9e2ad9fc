"""The mock backend (:class:`MockBackend`, hal/contract.py): a simulated machine
(``world.py``) built from a spec, the daemon's embedded default.

It opens no hardware, so its probe is the contract's default. Its step IO's compiled lines
are the world's mechanics and timeline (``MockWorld.simulated_lines``): the compiled step
core runs on the mock as on GPIO lines.

:func:`build` and :func:`build_step_io` are the same for tests and benchmarks that build a
simulated machine by hand (the daemon goes through the registry).

Threads: as the world's (``world.py``); the backend object holds no state.
"""

from __future__ import annotations

from motorctl.hal.backends.mock.dspin_world import factory_of
from motorctl.hal.backends.mock.world import MockStepOutputs, MockWorld, world_of
from motorctl.hal.compiled_lines import CompiledLines
from motorctl.hal.contract import Backend
from motorctl.hal.interfaces import Clock, Hardware, StepIO
from motorctl.hal.spec import HardwareSpec
from motorctl.hal.spi import SpiFactory


def _timeline_len(spec: HardwareSpec) -> int | None:
    timeline_len = spec.options.get("timeline_len", 100_000)
    if timeline_len is not None and not isinstance(timeline_len, int):
        raise ValueError("timeline_len must be an int or None")
    return timeline_len


class MockBackend(Backend):
    """The simulated machine as a backend.

    ``options["executor_process"]``: the step executor runs in another process, so the
    axes' mechanics go to shared memory (its descriptor in ``Hardware.step_io_fds``: the
    executor's process gets a copy as its ``mechanics`` option). ``options["timeline_len"]``
    bounds the timeline (None: everything); ``options["timeline_file"]``: where the
    executor's own process writes its timeline when its step IO closes.
    """

    name = "mock"

    def build(self, spec: HardwareSpec, clock: Clock) -> Hardware:
        share = bool(spec.options.get("executor_process", False))
        return MockWorld(spec, clock, _timeline_len(spec), share=share).hardware()

    def simulated_spi(self, spec: HardwareSpec, clock: Clock) -> SpiFactory | None:
        """A world of its own's dSPIN chains, for ``--probe`` (chips at power-up)."""
        return factory_of(spec, MockWorld(spec, clock, _timeline_len(spec)).axes, clock)

    def build_step_io(self, spec: HardwareSpec, clock: Clock, parent: Hardware | None) -> StepIO:
        """STEP/DIR and end stops: on the parent's world in-process, else on the shared
        mechanics (``options["mechanics"]``) or a world of its own."""
        if parent is not None:
            return world_of(parent).step_io()
        mechanics = spec.options.get("mechanics")
        if mechanics is not None and not isinstance(mechanics, int):
            raise ValueError("mechanics must be the descriptor of the shared mechanics")
        world = MockWorld(spec, clock, _timeline_len(spec), mechanics=mechanics)
        io = world.step_io()
        path = spec.options.get("timeline_file")
        if isinstance(path, str):
            io.closers.append(lambda: world.dump_timeline(path))
        io.closers.append(world.close)
        return io

    def compiled_lines(self, io: StepIO) -> CompiledLines | str:
        outputs = io.outputs
        if not isinstance(outputs, MockStepOutputs):
            return "not the mock's step IO"
        return outputs.world.simulated_lines(outputs.axes)


def build(spec: HardwareSpec, clock: Clock) -> Hardware:
    """A simulated machine's daemon part, as the registry builds it."""
    return MockBackend().build(spec, clock)


def build_step_io(spec: HardwareSpec, clock: Clock, parent: Hardware | None = None) -> StepIO:
    """A simulated machine's step IO with its compiled lines, as the registry opens it."""
    return MockBackend().open_step_io(spec, clock, parent)
