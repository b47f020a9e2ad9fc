"""The mock dSPIN chip (dspin_chip.py) at the register level, driven byte by byte as its
shift register latches them: answers, the write conditions and the flags they raise,
GetStatus against GetParam(STATUS), the faults, FLAG and BUSY."""

from __future__ import annotations

import pytest

from motorctl.hal.backends.mock.dspin_chip import DspinChip, wrap22
from motorctl.hal.dspin import commands as c
from motorctl.hal.dspin.chips import L6470, L6472, L6480, POWERSTEP01_VOLTAGE, Chip
from motorctl.hal.dspin.commands import Op


def send(chip: DspinChip, data: bytes) -> bytes:
    """A chain of one: each byte in, the byte the chip shifted out meanwhile back."""
    out = []
    for byte in data:
        out.append(chip.shift_out())
        chip.receive(byte)
    return bytes(out)


def ask(chip: DspinChip, cmd: c.Command) -> int:
    assert send(chip, cmd.encode()) == bytes(len(cmd.encode()))  # 0x00 during a command
    return int.from_bytes(send(chip, bytes(cmd.reply_length)), "big")


def status(chip: DspinChip) -> int:
    return ask(chip, c.get_param(chip.chip.status_register))


def get_status(chip: DspinChip) -> int:
    return ask(chip, c.simple(Op.GET_STATUS))


def reg(chip: DspinChip, name: str) -> int:
    return ask(chip, c.get_param(chip.chip.registers[name]))


@pytest.mark.parametrize("model", [L6470, L6472, L6480, POWERSTEP01_VOLTAGE])
def test_power_up(model: Chip) -> None:
    chip = DspinChip(model)
    assert reg(chip, "CONFIG") == model.config.reset
    assert reg(chip, "ACC") == 0x08A and reg(chip, "MAX_SPEED") == 0x041
    assert reg(chip, "STEP_MODE") == 0x07
    word = status(chip)
    decoded = model.status.decode(word)
    assert decoded.hiz and not decoded.busy and decoded.faults == ("UVLO",)
    assert chip.flag  # UVLO at power-up pulls FLAG low
    assert status(chip) == word  # GetParam(STATUS) clears nothing
    assert get_status(chip) == word
    assert model.status.decode(status(chip)).faults == ()  # GetStatus did
    assert not chip.flag


def test_getstatus_clears_latched_flags_and_getparam_status_does_not() -> None:
    chip = DspinChip(L6470)
    get_status(chip)
    chip.inject("STEP_LOSS_A")
    chip.inject("STEP_LOSS_A", present=False)  # gone, but latched
    chip.inject("OCD")  # still present
    for _ in range(2):
        assert L6470.status.decode(status(chip)).faults == ("OCD", "STEP_LOSS_A")
    assert L6470.status.decode(get_status(chip)).faults == ("OCD", "STEP_LOSS_A")
    assert L6470.status.decode(status(chip)).faults == ("OCD",)  # still there
    chip.inject("OCD", present=False)
    assert L6470.status.decode(get_status(chip)).faults == ("OCD",)
    assert L6470.status.decode(status(chip)).faults == ()


def configure(chip: DspinChip, microsteps: int = 1) -> None:
    """Out of power-up: clear UVLO, full steps, SW_MODE as reset."""
    get_status(chip)
    send(
        chip,
        c.set_param(chip.chip.registers["STEP_MODE"], chip.chip.step_mode(microsteps)).encode(),
    )


@pytest.mark.parametrize(("model", "flag"), [(L6470, "NOTPERF_CMD"), (L6480, "CMD_ERROR")])
def test_a_hiz_only_register_written_while_running_is_refused(model: Chip, flag: str) -> None:
    chip = DspinChip(model)
    configure(chip)
    send(chip, c.run(c.FORWARD, 10000).encode())
    chip.advance(0.01)
    for name, value in (("STEP_MODE", 0x03), ("CONFIG", 0x0000), ("ACC", 0x100)):
        before = reg(chip, name)
        send(chip, c.set_param(model.registers[name], value).encode())
        assert reg(chip, name) == before, name
        assert model.status.decode(get_status(chip)).command_errors == (flag,)
    send(chip, c.set_param(model.registers["MAX_SPEED"], 0x100).encode())  # always writable
    assert reg(chip, "MAX_SPEED") == 0x100
    assert model.status.decode(get_status(chip)).command_errors == ()
    # stopped but not in HiZ: ACC is writable, STEP_MODE still not
    send(chip, c.simple(Op.HARD_STOP).encode())
    send(chip, c.set_param(model.registers["ACC"], 0x100).encode())
    assert reg(chip, "ACC") == 0x100
    send(chip, c.set_param(model.registers["STEP_MODE"], 0x03).encode())
    assert model.status.decode(get_status(chip)).command_errors == (flag,)
    send(chip, c.simple(Op.HARD_HIZ).encode())
    send(chip, c.set_param(model.registers["STEP_MODE"], 0x03).encode())
    assert reg(chip, "STEP_MODE") == 0x03


def test_a_wrong_command_is_ignored_and_the_next_byte_is_a_command_again() -> None:
    chip = DspinChip(L6470)
    get_status(chip)
    # SetParam(SPEED): SPEED is read-only -> WRONG_CMD at once; 0xD0 is then GetStatus
    assert send(chip, bytes([0x04, 0xD0, 0x00, 0x00]))[2:] != bytes(2)
    chip2 = DspinChip(L6470)
    get_status(chip2)
    send(chip2, bytes([0x1A]))  # no register at 0x1A on an L6470
    assert L6470.status.decode(status(chip2)).command_errors == ("WRONG_CMD",)
    assert L6480.status.decode(status(DspinChip(L6480))).command_errors == ()


def test_a_new_answer_replaces_one_not_sent_yet() -> None:
    chip = DspinChip(L6470)
    get_status(chip)
    send(chip, c.set_param(L6470.registers["MARK"], 0x123456).encode())
    send(chip, c.get_param(L6470.registers["MARK"]).encode())
    assert send(chip, bytes(1)) == bytes([0x12])
    send(chip, c.get_param(L6470.registers["CONFIG"]).encode())  # aborts MARK's answer
    assert send(chip, bytes(2)) == bytes([0x2E, 0x88])
    assert send(chip, bytes(1)) == bytes(1)


def test_positioning_commands_wait_for_busy_and_move_for_a_standstill() -> None:
    chip = DspinChip(L6470)
    configure(chip)
    send(chip, c.go_to(1000).encode())
    chip.advance(0.05)
    assert chip.busy
    send(chip, c.go_to(5).encode())
    send(chip, c.move(c.FORWARD, 5).encode())
    assert L6470.status.decode(get_status(chip)).command_errors == ("NOTPERF_CMD",)
    chip.advance(5)
    assert not chip.busy and reg(chip, "ABS_POS") == 1000
    send(chip, c.run(c.REVERSE, 5000).encode())  # Run: any time
    chip.advance(1)
    assert not chip.busy  # at its speed: BUSY released, so a GoTo is taken
    send(chip, c.simple(Op.GO_HOME).encode())
    assert L6470.status.decode(get_status(chip)).command_errors == ()
    send(chip, c.move(c.FORWARD, 5).encode())  # Move is not: the motor runs
    assert L6470.status.decode(get_status(chip)).command_errors == ("NOTPERF_CMD",)


def test_faults_stop_the_motor_and_pull_flag() -> None:
    chip = DspinChip(L6480)
    configure(chip)
    send(chip, c.run(c.FORWARD, 20000).encode())
    chip.advance(0.2)
    assert not chip.flag
    chip.inject("STEP_LOSS_B")  # a stall: flagged, the chip keeps going
    assert chip.flag and not chip.motion.stopped
    chip.inject("STEP_LOSS_B", present=False)
    send(chip, c.set_param(L6480.registers["ALARM_EN"], 0xDF).encode())  # refused: running
    get_status(chip)
    chip.inject("TH_SD")  # thermal shutdown: bridges off at once
    word = status(chip)
    decoded = L6480.status.decode(word)
    assert decoded.hiz and decoded.motor.name == "STOPPED" and not decoded.busy
    assert decoded.faults == ("TH_STATUS=BRIDGE_SHUTDOWN",) and chip.flag
    send(chip, c.run(c.FORWARD, 100).encode())  # refused while the bridges are held off
    assert L6480.status.decode(get_status(chip)).command_errors == ("CMD_ERROR",)
    chip.inject("TH_SD", present=False)
    get_status(chip)
    assert not chip.flag
    # ALARM_EN decides what reaches FLAG: without the stall bit (5) a stall does not
    send(chip, c.set_param(L6480.registers["ALARM_EN"], 0xDF).encode())
    chip.inject("STEP_LOSS_A")
    assert not chip.flag and L6480.status.decode(status(chip)).faults == ("STEP_LOSS_A",)
    with pytest.raises(ValueError, match="unknown fault 'STALL'"):
        chip.inject("STALL")


def test_ocd_turns_the_bridges_off_only_with_oc_sd() -> None:
    chip = DspinChip(L6470)
    configure(chip)
    send(chip, c.run(c.FORWARD, 20000).encode())
    chip.advance(0.1)
    chip.inject("OCD")  # OC_SD is 1 at reset
    assert chip.hiz and chip.motion.stopped
    chip2 = DspinChip(L6470)
    configure(chip2)
    config = L6470.config
    send(chip2, c.set_param(config, config.field("OC_SD").put(0x2E88, 0)).encode())
    send(chip2, c.run(c.FORWARD, 20000).encode())
    chip2.advance(0.1)
    chip2.inject("OCD")
    assert not chip2.hiz and not chip2.motion.stopped


def test_reset_device_and_reset_pos() -> None:
    chip = DspinChip(POWERSTEP01_VOLTAGE)
    configure(chip, 16)
    assert chip.microsteps == 16
    send(chip, c.set_param(chip.chip.registers["STEP_MODE"], 0x0C).encode())  # current mode
    assert chip.chip.name == "powerSTEP01 (current mode)" and chip.microsteps == 16
    send(chip, c.move(c.FORWARD, 100).encode())
    chip.advance(2)
    assert reg(chip, "ABS_POS") == 100
    send(chip, c.simple(Op.RESET_POS).encode())
    assert reg(chip, "ABS_POS") == 0 and chip.shaft == 100
    send(chip, c.simple(Op.RESET_DEVICE).encode())
    assert chip.chip.name == "powerSTEP01 (voltage mode)" and reg(chip, "STEP_MODE") == 0x07
    assert chip.hiz and POWERSTEP01_VOLTAGE.status.decode(status(chip)).faults == ()


def test_abs_pos_wraps_at_22_bits() -> None:
    assert wrap22(2**21) == -(2**21) and wrap22(-(2**21) - 1) == 2**21 - 1
    chip = DspinChip(L6470)
    configure(chip)
    send(chip, c.set_param(L6470.registers["ABS_POS"], 2**21 - 3).encode())
    send(chip, c.move(c.FORWARD, 5).encode())
    chip.advance(1)
    assert reg(chip, "ABS_POS") == 0x200002  # -2^21 + 2, as the chip sends it
    # a Run wraps as it goes (down, back across), and GoTo_DIR goes in its DIR to a target
    # across the wrap
    send(chip, c.run(c.REVERSE, 0x1000).encode())  # 0x1000 * 2^-28 / 250 ns: 61 step/s
    chip.advance(0.1)
    send(chip, c.simple(Op.HARD_STOP).encode())
    back = chip.abs_pos
    assert 2**21 - 100 < back < 2**21  # wrapped back to the top
    before = chip.shaft
    send(chip, c.go_to_dir(c.FORWARD, -(2**21) + 3).encode())  # up through the wrap
    chip.advance(1)
    assert reg(chip, "ABS_POS") == 0x200003 and chip.shaft - before == 2**21 - back + 3
