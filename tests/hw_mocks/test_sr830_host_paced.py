"""The emulated SR830 on a host-paced clock (``simsr830://…&clock=host``).

Its time passes only with the host's waits, the bytes on the wire and, while the host
waits for an answer ``AGAN`` holds back, up to that answer. So the readings follow from
the seed and the host's commands and waits: a host that is slow between its commands
(real delays here) reads the same values as a fast one; one that waits longer reads
others.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.stanford_sr830 import Sr830LockIn
from hw_mocks import registry
from hw_mocks.clock import HostPacedClock, ScaledClock, wire_time_s
from hw_mocks.firmware.sr830 import ENBW_TIMES_TAU, Sr830Emulator
from hw_mocks.pty_server import serve_url
from hw_mocks.urlhandler.protocol_simsr830 import host_sleep, make_emulator
from instrument.bench.devices import open_bench
from instrument.bench.profile import load_profile

TAU = 0.03  # OFLT 7
SETUP = "OUTX 0;OFLT 7;OFSL 1;SENS 20"  # 30 ms, 12 dB/oct, 1 mV full scale


def _emulator(seed: int, noise: float = 1e-7) -> Sr830Emulator:
    emu = Sr830Emulator("t", clock=HostPacedClock(), output_interface=0, seed=seed,
                        input_noise_v_per_rthz=noise)
    emu.set_input(2e-4)
    assert emu.receive(SETUP.encode() + b"\n") == []
    return emu


def _readings(emu: Sr830Emulator, waits: list[float], host_delay_s: float = 0.0
              ) -> list[bytes]:
    """``SNAP? 1,2`` after each host wait (advancing the clock); ``host_delay_s`` of real
    time is spent between the commands as well, as a slow or loaded host would."""
    out = []
    for wait in waits:
        time.sleep(host_delay_s)
        emu.clock.advance(wait)
        time.sleep(host_delay_s)
        (reply,) = emu.receive(b"SNAP? 1,2\n")
        out.append(reply)
    return out


WAITS = [0.5, 7 * TAU, 7 * TAU, 0.01, 7 * TAU, 2.0, 7 * TAU]


def test_a_slow_host_reads_the_same_values_as_a_fast_one():
    fast = _readings(_emulator(5), WAITS)
    slow = _readings(_emulator(5), WAITS, host_delay_s=0.02)
    assert slow == fast
    # …and they are noisy readings: they differ from each other and from another seed
    assert len(set(fast)) == len(fast)
    assert _readings(_emulator(6), WAITS) != fast


def test_the_host_waits_are_the_time_the_filter_and_noise_see():
    emu = _emulator(5, noise=0.0)
    emu.set_input(0.0)
    emu.clock.advance(1.0)
    emu.set_input(5e-4)  # a step now
    t_step = emu.clock.now()
    for wait in (0.0, 7 * TAU, 3 * TAU):
        emu.clock.advance(wait)
        (reply,) = emu.receive(b"OUTP? 1\n")
        # executed once its 8 bytes had arrived; its reply's bytes then took their time
        x = (emu.clock.now() - wire_time_s(len(reply), 9600) - t_step) / TAU
        # two cascaded poles: 1 − (1 + x) e^(−x) of the step
        assert float(reply) == pytest.approx(5e-4 * (1 - (1 + x) * np.exp(-x)), rel=1e-5)
    assert x > 10  # settled (99.95 %)

    # the noise: X over many readings 7 τ apart has the ENBW's standard deviation
    emu = _emulator(9, noise=1e-7)
    xs = []
    for _ in range(400):
        emu.clock.advance(7 * TAU)
        (reply,) = emu.receive(b"OUTP? 1\n")
        xs.append(float(reply))
    sigma = 1e-7 * np.sqrt(ENBW_TIMES_TAU[2] / TAU)
    # 400 nearly independent readings: the sample σ is within ±3.5/√800 ≈ 12 % (3.5σ)
    assert np.std(xs, ddof=1) == pytest.approx(sigma, rel=0.12)
    assert np.mean(xs) == pytest.approx(2e-4, abs=4 * sigma / np.sqrt(400))


def test_bytes_on_the_wire_take_their_time_at_the_line_rate():
    emu = _emulator(1)
    t0 = emu.clock.now()
    (reply,) = emu.receive(b"SNAP? 1,2\n")
    assert emu.clock.now() - t0 == pytest.approx(wire_time_s(10 + len(reply), 9600))
    assert wire_time_s(96, 9600) == pytest.approx(0.1)  # 10 bits a byte (8N1)


def test_auto_gain_ends_when_the_host_waits_for_its_answer():
    registry.reset()
    url = "simsr830://paced?clock=host&outx=0&seed=2"
    li = Sr830LockIn(url, name="lockin", sleep=host_sleep(url))
    emu = registry.get("simsr830", "paced")
    emu.set_input(3e-3)
    li.time_constant_s = 0.1
    t0 = emu.clock.now()
    full_scale = li.auto_gain(timeout=30.0)
    # the 10 τ it keeps the interpreter busy passed on the emulated clock, not 30 s
    assert emu.clock.now() - t0 >= 10 * 0.1
    assert full_scale == pytest.approx(5e-3)  # the smallest with 3 mV ≤ 0.8 full scale
    t1 = emu.clock.now()
    assert li.settle() == pytest.approx(0.7)  # 7 τ at the power-up 12 dB/oct
    # the wait, and the wire time of the two queries that find it (OFSL?, OFLT?)
    assert 0.7 <= emu.clock.now() - t1 <= 0.7 + wire_time_s(40, 9600)
    li.close()


def test_the_url_option_is_checked():
    with pytest.raises(ValueError, match="only choice is 'host'"):
        make_emulator("x", {"clock": "wall"})
    with pytest.raises(ValueError, match="no speed= or step="):
        make_emulator("x", {"clock": "host", "speed": "2"})
    assert isinstance(make_emulator("x", {}).clock, ScaledClock)
    registry.reset()
    assert host_sleep("simsr830://wall?seed=1") is None  # the driver's time.sleep is right


def test_a_pty_serves_a_host_paced_url_on_the_wall_clock():
    registry.reset()
    with serve_url("simsr830://ptylockin?clock=host&seed=1") as server:
        assert isinstance(server.emulator.clock, ScaledClock)


def test_the_spectral_sim_bench_paces_its_lock_in_by_the_driver_waits():
    with open_bench(load_profile("sim-spectral")) as bench:
        emu = registry.get("simsr830", "lockin")
        assert isinstance(emu.clock, HostPacedClock)
        t0 = emu.clock.now()
        waited = bench.lockin.settle()
        # the settle time, and the wire time of the two queries that find it (OFSL?, OFLT?)
        assert waited == pytest.approx(7 * 0.03)
        assert waited <= emu.clock.now() - t0 <= waited + wire_time_s(40, 9600)
