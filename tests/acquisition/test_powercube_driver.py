"""One scripted exchange per PowerCube command, plus corruption and silence."""

import struct

import pytest

from rangeseg_o3d.acquisition.errors import DeviceTimeout, PowerCubeProtocolError
from rangeseg_o3d.acquisition.powercube import FROM_MODULE, encode_frame, pack_float
from rangeseg_o3d.acquisition.powercube_driver import PowerCube


def to(hexstr):
    return encode_frame(11, bytes.fromhex(hexstr))


def back(hexstr):
    return encode_frame(11, bytes.fromhex(hexstr), direction=FROM_MODULE)


def state_reply(word):
    return back("0A 27" + struct.pack("<I", word).hex())


def make(scripted, script, **kw):
    return PowerCube(scripted(script), timeout=kw.pop("timeout", 0.2), reply_timeout=kw.pop("reply_timeout", 0.02),
                     poll_interval=0.0, **kw)


def test_reset_home_halt(scripted):
    cube = make(scripted, [(bytes.fromhex("02 05 61 00 66 03"), back("00")),
                           (bytes.fromhex("02 05 61 01 67 03"), back("01")),
                           (bytes.fromhex("02 05 61 10 82 68 03"), back("02"))])
    cube.reset()
    cube.home()
    cube.halt()


def test_get_state_and_position(scripted):
    cube = make(scripted, [(bytes.fromhex("02 05 62 0A 27 98 03"), state_reply(0x8002)),
                           (bytes.fromhex("02 05 62 0A 3C AD 03"), bytes.fromhex("02 09 66 0A 3C 9A 99 99 3E C1 03")),
                           (bytes.fromhex("02 05 62 0A 3C AD 03"), bytes.fromhex("02 09 66 0A 3C 9A 99 99 3E C1 03"))])
    assert cube.state() == 0x8002
    assert cube.position() == pytest.approx(0.3, abs=1e-7)


def test_set_ramp_is_verified_by_read_back(scripted):
    vel, acc = pack_float(0.5).hex(), pack_float(1.0).hex()
    cube = make(scripted, [
        (bytes.fromhex("02 05 66 08 4F 00 00 00 3F 10 82 03"), back("08 4F")),
        (to("0A 4F"), back("0A 4F" + pack_float(0.25).hex())),  # a corrupted set stored 0.25
        (to("08 4F" + vel), back("08 4F")),
        (to("0A 4F"), back("0A 4F" + vel)),
        (to("08 50" + acc), back("08 50")),
        (to("0A 50"), back("0A 50" + acc)),
    ])
    cube.set_ramp(0.5, 1.0)


def test_move_and_wait(scripted):
    cube = make(scripted, [(bytes.fromhex("02 05 66 0B 04 CD CC CC BE A0 03"), back("0B 04")),
                           (to("0A 27"), state_reply(0x0802)),
                           (to("0A 27"), state_reply(0x8002))])
    cube.move_to(-0.4)
    cube.wait_until_stopped(1.0)


def test_error_state_raises(scripted):
    cube = make(scripted, [(to("0A 27"), state_reply(0x0011))])
    with pytest.raises(PowerCubeProtocolError, match="error state"):
        cube.wait_until_stopped(1.0)


def test_initialise_homes_then_sets_ramp(scripted):
    vel, acc = pack_float(0.5).hex(), pack_float(2.0).hex()
    cube = make(scripted, [(to("00"), back("00")), (to("01"), back("01")),
                           (to("0A 27"), state_reply(0x0800)), (to("0A 27"), state_reply(0x8002)),
                           (to("08 4F" + vel), back("08 4F")), (to("0A 4F"), back("0A 4F" + vel)),
                           (to("08 50" + acc), back("08 50")), (to("0A 50"), back("0A 50" + acc))])
    cube.initialise(velocity=0.5, acceleration=2.0, timeout=1.0)


def test_corrupted_reply_resent_foreign_module_ignored(scripted):
    good = state_reply(0x2)
    bad = bytearray(good)
    bad[4] ^= 0x01
    other = encode_frame(12, bytes.fromhex("0A 27 00 00 00 00"), direction=FROM_MODULE)
    cube = make(scripted, [(to("0A 27"), b"\xff" + bytes(bad)), (to("0A 27"), other + b"\x10\x03" + good)])
    assert cube.state() == 0x2 and cube.stats["bad_frames"] >= 1


def test_position_must_settle(scripted):
    replies = [(to("0A 3C"), back("0A 3C" + pack_float(0.1 * k).hex())) for k in range(3)]
    cube = make(scripted, replies, attempts=3)
    with pytest.raises(PowerCubeProtocolError, match="settle"):
        cube.position()


def test_silent_module_times_out(scripted):
    cube = make(scripted, [(to("0A 27"), b"")] * 20, timeout=0.05)
    with pytest.raises(DeviceTimeout, match="scripted"):
        cube.state()
    assert 2 <= cube.stats["sent"] < 20
    cube.transport.script.clear()  # how many resends fit in the timeout is not the point


def test_bad_values(scripted):
    cube = make(scripted, [])
    with pytest.raises(ValueError, match="finite"):
        cube.move_to(float("nan"))
    with pytest.raises(ValueError, match="positive"):
        cube.set_ramp(0.0, 1.0)
    with pytest.raises(ValueError, match="module_id"):
        PowerCube(scripted([]), module_id=40)
