"""The emulated PM100USB's noise keyed to the bench state (ADR 0111): readings taken at
rest before a run (a server's idle polls) leave the run's readings unchanged, and the
readings stay independent draws of the documented noise (σ = noise floor / R in the
dark), also over the same states under different seeds."""

from __future__ import annotations

import math

import numpy as np

from hw_mocks.firmware.pm100usb import Pm100usbFirmware

#: The states of a "run": (position, light on) pairs, a light and a dark reading each.
RUN = [(float(p), on) for p in range(-70, 81, 10) for on in (True, False)]


def _meter(seed: int) -> tuple[Pm100usbFirmware, list]:
    """A meter in the dark (its reading: dark current and noise) whose noise is keyed to
    ``state[0]``, which the test moves."""
    fw = Pm100usbFirmware("keyed", seed=seed)
    state: list = [("rest", False)]
    fw.noise_state = lambda: state[0]
    return fw, state


def _read(fw: Pm100usbFirmware) -> float:
    (reply,) = fw.receive(b"MEAS:POW?\n")
    return float(reply)


def _run(fw: Pm100usbFirmware, state: list) -> np.ndarray:
    out = []
    for s in RUN:
        state[0] = s
        out.append(_read(fw))
    return np.array(out)


def test_idle_readings_before_a_run_leave_its_readings_unchanged():
    fresh, s1 = _meter(7)
    polled, s2 = _meter(7)
    for _ in range(25):  # the server's idle polls, all at the resting state
        _read(polled)
    np.testing.assert_array_equal(_run(fresh, s1), _run(polled, s2))
    other, s3 = _meter(8)
    assert not np.array_equal(_run(fresh, s1), _run(other, s3))  # a second run, a new seed


def test_keyed_readings_are_independent_draws_of_the_documented_noise():
    """500 seeds of the same run (the same states each time, as a plan's are): every
    reading's spread over the seeds is σ, and the mean of a run's light readings minus
    the mean of its dark ones (what a dark subtraction averages) scatters as independent
    draws do: σ·sqrt(2/n) within 10 % (500 seeds: ±3 % at 1σ)."""
    fw0, _ = _meter(0)
    r = fw0.responsivity_a_per_w(fw0.wavelength_nm)
    sigma = fw0.noise_floor_a / r  # W, in the dark
    dark = fw0.dark_current_a / r
    runs = np.array([_run(*_meter(seed)) for seed in range(500)]) - dark
    assert abs(runs.mean()) < 4 * sigma / math.sqrt(runs.size)
    per_reading = runs.std(axis=0, ddof=1) / sigma
    assert np.all(np.abs(per_reading - 1) < 0.2), per_reading  # each ±3 % at 1σ
    on = np.array([s[1] for s in RUN])
    net = runs[:, on].mean(axis=1) - runs[:, ~on].mean(axis=1)
    expected = sigma * math.sqrt(1 / on.sum() + 1 / (~on).sum())
    assert abs(net.std(ddof=1) / expected - 1) < 0.1
    # and a run's own dark readings spread by σ (what the reduction measures σ₀ from)
    within = runs[:, ~on].std(axis=1, ddof=1).mean() / sigma
    assert abs(within - 1) < 0.05  # 500 runs of 16: ±1 % at 1σ (the mean of s is ≈0.98σ)
