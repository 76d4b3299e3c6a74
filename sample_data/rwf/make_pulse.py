"""Regenerate ``pulse_example.csv``: a synthetic, bench-like pulse recording (not a real measurement).

A two-sided Gaussian in time (rise std 70 ns, decay std 80 ns, FWHM 176.6 ns = 26.5 m in
range), peak 5 ns after the gating reference, sampled at 250 MHz (4 ns) with additive
detector noise of 0.3 % of the peak clipped at zero, as a bench digitiser would record it.
Run: ``python sample_data/rwf/make_pulse.py`` (deterministic: fixed SeedSequence).
"""

from pathlib import Path

import numpy as np

rng = np.random.default_rng(np.random.SeedSequence(20250221))
t = np.arange(-400, 604, 4.0)  # ns
d = t - 5.0
intensity = np.exp(-0.5 * (d / np.where(d < 0, 70.0, 80.0)) ** 2)
intensity = np.clip(intensity + rng.normal(0.0, 0.003, t.size), 0.0, None)
out = Path(__file__).with_name("pulse_example.csv")
with open(out, "w") as fh:
    fh.write("# Synthetic pulse recording for lidarcal examples and tests (see make_pulse.py).\n")
    fh.write("# time_ns: emission time relative to the gating reference; "
             "intensity: linear, arbitrary scale.\n")
    fh.write("time_ns,intensity\n")
    for ti, yi in zip(t, intensity, strict=True):
        fh.write(f"{ti:.0f},{yi:.5f}\n")
