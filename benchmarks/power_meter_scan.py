"""The zero-latency scan of the GUI and server benchmarks: an in-plane plan on the ideal
bench with the power meter only, about ``n_target`` points (20 incidence angles × the
detector angles that make it up)."""

from __future__ import annotations


def power_meter_scan(n_target: int, name: str) -> str:
    """The plan file's text (TOML), named ``name``."""
    n_r = max(3, n_target // 20)
    return f"""
[plan]
kind = "brdf_in_plane"
name = "{name}"
[sample]
name = "ideal"
[scan]
theta_i = {{ start = 5.0, stop = 81.0, step = 4.0 }}
theta_r = {{ start = -85.0, stop = 85.0, step = {170.0 / (n_r - 1):.6f} }}
skip_beam_points = true
[acquisition]
mode = "fixed"
exposure_us = 1000
detectors = ["power_meter"]
"""
