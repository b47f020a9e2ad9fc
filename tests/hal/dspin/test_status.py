"""STATUS decoding (status.py) per model: the bits where the L6470, L6472 and L6480 /
powerSTEP01 differ, the active-low flags, TH_STATUS."""

from __future__ import annotations

from motorctl.hal.dspin.chips import L6470, L6472, L6480, POWERSTEP01_CURRENT
from motorctl.hal.dspin.status import (
    L6470_STATUS,
    L6472_STATUS,
    L6480_STATUS,
    MotorState,
    ThermalState,
)
from tests.hal.dspin.test_registers import doc_table

#: no condition at all: every active-low flag high, BUSY high (not busy)
L6470_IDLE = 0x7E02  # BUSY, UVLO, TH_WRN, TH_SD, OCD, STEP_LOSS_A, STEP_LOSS_B high
L6480_IDLE = 0xE602  # BUSY, UVLO, UVLO_ADC, OCD, STEP_LOSS_A, STEP_LOSS_B high


def test_the_idle_words() -> None:
    assert L6470_STATUS.idle_word | 0x0002 == L6470_IDLE
    assert L6480_STATUS.idle_word | 0x0002 == L6480_IDLE
    assert L6472_STATUS.idle_word | 0x0002 == 0x1E02  # no stall bits
    for layout, word in ((L6470_STATUS, L6470_IDLE), (L6480_STATUS, L6480_IDLE)):
        status = layout.decode(word)
        assert status.faults == () and status.command_errors == () and status.warnings == ()
        assert not status.busy and not status.hiz and status.motor is MotorState.STOPPED


def test_bit_13_is_a_stall_on_the_l6470_and_an_overcurrent_on_the_l6480() -> None:
    assert L6470.status.decode(L6470_IDLE & ~0x2000).faults == ("STEP_LOSS_A",)
    assert L6480.status.decode(L6480_IDLE & ~0x2000).faults == ("OCD",)
    assert L6472.status.decode(L6470_IDLE & ~0x2000).faults == ()  # unused there
    assert L6470.status.decode(L6470_IDLE & ~0x1000).faults == ("OCD",)
    assert L6480.status.decode(L6480_IDLE & ~0x4000).faults == ("STEP_LOSS_A",)
    assert L6480.status.decode(L6480_IDLE & ~0x8000).faults == ("STEP_LOSS_B",)
    assert L6470.status.decode(L6470_IDLE & ~0x4000).faults == ("STEP_LOSS_B",)


def test_the_command_error_bits() -> None:
    assert L6470.status.decode(L6470_IDLE | 0x0080).command_errors == ("NOTPERF_CMD",)
    assert L6470.status.decode(L6470_IDLE | 0x0100).command_errors == ("WRONG_CMD",)
    assert L6480.status.decode(L6480_IDLE | 0x0080).command_errors == ("CMD_ERROR",)
    l6480 = L6480.status.decode(L6480_IDLE | 0x0100)  # bit 8 is step-clock mode there
    assert l6480.command_errors == () and l6480["STCK_MOD"] == 1
    assert L6470.status.decode(L6470_IDLE | 0x8000)["SCK_MOD"] == 1


def test_thermal_flags() -> None:
    l6470 = L6470.status
    assert l6470.decode(L6470_IDLE & ~0x0400).warnings == ("TH_WRN",)
    assert l6470.decode(L6470_IDLE & ~0x0400).faults == ()
    assert l6470.decode(L6470_IDLE & ~0x0800).faults == ("TH_SD",)
    assert l6470.decode(L6470_IDLE & ~0x0800).thermal is ThermalState.BRIDGE_SHUTDOWN
    l6480 = POWERSTEP01_CURRENT.status
    warning = l6480.decode(L6480_IDLE | 1 << 11)
    assert warning.thermal is ThermalState.WARNING
    assert warning.faults == () and warning.warnings == ("TH_STATUS=WARNING",)
    assert l6480.decode(L6480_IDLE | 2 << 11).faults == ("TH_STATUS=BRIDGE_SHUTDOWN",)
    assert l6480.decode(L6480_IDLE | 3 << 11).faults == ("TH_STATUS=DEVICE_SHUTDOWN",)


def test_undervoltage_and_the_state_flags() -> None:
    assert L6470.status.decode(L6470_IDLE & ~0x0200).faults == ("UVLO",)
    assert L6480.status.decode(L6480_IDLE & ~0x0600).faults == ("UVLO", "UVLO_ADC")
    status = L6480.status.decode((L6480_IDLE & ~0x0002) | 0x0001 | 0x0004 | 0x0008 | 0x0010)
    assert status.busy and status.hiz and status.switch_closed and status.switch_event
    assert status.forward
    assert status.active(*()) == ()
    for state in MotorState:
        assert L6470.status.decode(L6470_IDLE | state << 5).motor is state
    flags = L6470.status.decode(L6470_IDLE).flags
    assert flags["UVLO"] == 0 and flags["BUSY"] == 0 and flags["MOT_STATUS"] == 0
    assert "STEP_LOSS_A" not in L6472.status.decode(0).flags


def test_a_status_reads_as_its_flags() -> None:
    text = str(L6470.status.decode((L6470_IDLE & ~0x2002) | 0x0001 | 1 << 5))
    assert text == "0x5E21 ACCELERATION HiZ BUSY STEP_LOSS_A"


def test_latched_bits() -> None:
    # SW_EVN, NOTPERF_CMD, WRONG_CMD, UVLO, TH_WRN, TH_SD, OCD, STEP_LOSS_A/B
    assert L6470_STATUS.latched_mask == 0x7F88
    # SW_EVN, CMD_ERROR, UVLO, UVLO_ADC, TH_STATUS, OCD, STEP_LOSS_A/B
    assert L6480_STATUS.latched_mask == 0xFE88
    assert L6472_STATUS.unused == 0x6000 and L6470_STATUS.unused == 0


def test_docs_status_table_is_the_code_s() -> None:
    rows = doc_table("bit")
    assert [int(r[0]) for r in rows] == list(range(16))
    for column, layout in ((1, L6470_STATUS), (2, L6472_STATUS), (3, L6480_STATUS)):
        for row in rows:
            bit, cell = int(row[0]), row[column]
            name = cell.removesuffix(" (low)")
            covering = [f for f in layout.flags if f.mask >> bit & 1]
            if name == "-":
                assert covering == [], (layout.name, bit)
                continue
            assert [f.name for f in covering] == [name], (layout.name, bit)
            assert covering[0].active_low == cell.endswith("(low)"), (layout.name, bit)
