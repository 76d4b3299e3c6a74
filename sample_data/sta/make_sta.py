"""Write the synthetic WindCube ``.sta`` examples of this folder (both dialects, firmware 2.x) and a mast CSV.

The files follow the format as described in lidarcal's STA reader (``lidarcal.conditions.stafile``):
Latin-1 text, tab-separated, a ``HeaderSize=N`` / ``HeaderLength=N`` first line, ``key=value``
header lines with ``****`` separators and a section title, the column names on line N + 2.
Values are made up (seeded power-law profiles, CNR decreasing with height): they are examples
of the format, not measurements.

    python sample_data/sta/make_sta.py            # rewrites the four files next to this script
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SEED = 20240301
PERIOD = np.timedelta64(600, "s")


def profiles(n: int, z: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Ten-minute statistics on (period, height): power-law speeds, TI 6-12 %, CNR falling with height."""
    u80 = 8.0 + np.cumsum(rng.normal(0.0, 0.4, n))
    alpha = 0.18 + rng.normal(0.0, 0.04, n)
    speed = u80[:, None] * (z / 80.0) ** alpha[:, None]
    disp = speed * rng.uniform(0.06, 0.12, speed.shape)
    direction = np.mod(245.0 + np.cumsum(rng.normal(0, 3.0, n))[:, None] + 2.0 * np.log(z / 40.0), 360.0)
    cnr = -11.0 - 0.07 * (z - 40.0)[None, :] + rng.normal(0.0, 0.6, speed.shape)
    avail = np.full(speed.shape, 100.0)
    return {"speed": speed, "disp": disp, "dir": direction, "cnr": cnr, "avail": avail}


def cell(x: float, fmt: str) -> str:
    """Format one value; ``NaN`` marks a missing one."""
    return "NaN" if not np.isfinite(x) else format(x, fmt)


def avail_cell(x: float) -> str:
    """Availability as an integer or with two decimals."""
    return "NaN" if not np.isfinite(x) else (f"{x:.0f}" if float(x).is_integer() else f"{x:.2f}")


def newer(path: Path, rng: np.random.Generator) -> None:
    """Newer dialect: ``HeaderSize``, ``Timestamp (end of interval)``, ``<h>m ...`` groups."""
    z = np.array([40.0, 58.0, 78.0, 98.0, 118.0])
    n = 12
    end = np.datetime64("2024-03-01T00:10") + np.arange(n) * PERIOD
    v = profiles(n, z, rng)
    v["avail"][:, 3] = np.round(rng.uniform(85, 100, n), 2)
    v["avail"][:, 4] = np.round(rng.uniform(60, 95, n), 2)
    v["avail"][4, 4] = 73.5  # below the default 80 % threshold
    for key in ("speed", "disp", "dir", "cnr"):
        v[key][9:, 4] = np.nan  # beyond the signal's reach: all NaN with 0 % availability
    v["avail"][9:, 4] = 0.0
    header = [
        "Version=0.0.0-example",
        "ID System=WLS866-EXAMPLE",
        "Location=Example site (synthetic)",
        "GPS Location=Lat:55.600000°N, Long:12.100000°E",
        "****************************************",
        "Configuration",
        "ScanAngle (°)=28.000",
        "CNRThreshold=-22",
        "Altitudes (m)=" + "\t".join(f"{h:g}" for h in z),
        "****************************************",
    ]
    quantities = ["Wind Speed (m/s)", "Wind Speed Dispersion (m/s)", "Wind Speed min (m/s)",
                  "Wind Speed max (m/s)", "Wind Direction (°)", "Z-wind (m/s)", "Z-wind Dispersion (m/s)",
                  "CNR (dB)", "CNR min (dB)", "Dopp Spect Broad (m/s)", "Data Availability (%)"]
    names = ["Timestamp (end of interval)", "Int Temp (°C)", "Ext Temp (°C)", "Pressure (hPa)",
             "Rel Humidity (%)", "Wiper count", "Vbatt (V)"]
    for h in z:
        names += [f"{h:g}m {q}" for q in quantities] + [""]
    lines = [f"HeaderSize={len(header)}", *header, "\t".join(names)]
    for t in range(n):
        stamp = str(end[t].astype("datetime64[m]")).replace("-", "/").replace("T", " ")
        cells = [stamp, f"{28.0 + 0.1 * t:.1f}", f"{6.0 + 0.05 * t:.1f}", "1012.6", "81.0", "0", "24.2"]
        for k in range(z.size):
            s, d, c = v["speed"][t, k], v["disp"][t, k], v["cnr"][t, k]
            cells += [cell(s, ".2f"), cell(d, ".2f"), cell(s - 2.2 * d, ".2f"), cell(s + 2.4 * d, ".2f"),
                      cell(v["dir"][t, k], ".1f"), cell(0.02 * s - 0.1, ".2f"), cell(0.4 * d, ".2f"),
                      cell(c, ".1f"), cell(c - 4.0, ".1f"), cell(1.9 + 0 * s, ".2f"),
                      avail_cell(v["avail"][t, k]), ""]
        lines.append("\t".join(cells))
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))  # CRLF, as Windows software writes


def older(path: Path, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Older dialect: ``HeaderLength``, ``Date``, ``Vhm<i>`` groups with un-indexed CNR columns."""
    z = np.array([40.0, 60.0, 80.0, 100.0])
    n = 8
    end = np.datetime64("2024-03-02T00:10") + np.arange(n) * PERIOD
    v = profiles(n, z, rng)
    v["avail"][:, 3] = np.round(rng.uniform(80, 100, n), 0)
    header = [
        "ID System=WLS7-164",
        "Localisation=Example site B (synthetic)",
        "GPS Localisation=N 55°36.000' E 12°06.000'",
        "****",
        "ScanAngle(°)=27.80",
        "CNRThreshold=-22",
        "Altitudes(m)=" + "\t".join(f"{h:g}" for h in z),
        "Version=0.0-example",
    ]
    names = ["Date", "WiperCount", "Tm"]
    for i in range(1, z.size + 1):
        indexed = ("Vhm", "dVh", "VhMax", "VhMin", "Azim", "um", "du", "vm", "dv", "wm", "dw")
        names += [f"{q}{i}" for q in indexed]
        names += ["CNRm", "dCNR", "CNRmax", "CNRmin", "spectral_broadening", "dspectral_broadening",
                  f"Avail.{i}", ""]
    lines = [f"HeaderLength={len(header)}", *header, "\t".join(names)]
    for t in range(n):
        day, clock = str(end[t].astype("datetime64[s]")).split("T")
        y, m, d = day.split("-")
        cells = [f"{d}/{m}/{y} {clock}", "0", f"{5.5 + 0.05 * t:.1f}"]
        for k in range(z.size):
            s, dv, w, c = v["speed"][t, k], v["disp"][t, k], v["dir"][t, k], v["cnr"][t, k]
            u, vv = -s * np.sin(np.radians(w)), -s * np.cos(np.radians(w))
            cells += [cell(s, ".2f"), cell(dv, ".2f"), cell(s + 2.4 * dv, ".2f"), cell(s - 2.2 * dv, ".2f"),
                      cell(w, ".1f"), cell(u, ".2f"), cell(dv, ".2f"), cell(vv, ".2f"), cell(dv, ".2f"),
                      cell(0.02 * s - 0.1, ".2f"), cell(0.4 * dv, ".2f"),
                      cell(c, ".1f"), cell(0.8, ".1f"), cell(c + 2.5, ".1f"), cell(c - 4.0, ".1f"),
                      cell(1.9, ".2f"), cell(0.3, ".2f"), avail_cell(v["avail"][t, k]), ""]
        lines.append("\t".join(cells))
    path.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    return end - PERIOD, np.round(v["speed"][:, [1, 2]], 2)


def mast(path: Path, rows: tuple[np.ndarray, np.ndarray], rng: np.random.Generator) -> None:
    """Write a mast CSV for the older file's 60 and 80 m: interval-start stamps, mean and std per height."""
    out = ["Timestamp,Spd80mN,Spd80mNStd,Spd60mN,Spd60mNStd"]
    for start, (u60, u80) in zip(*rows, strict=True):
        s60, s80 = u60 * 1.01, u80 * 0.995  # a cup reading slightly apart from the lidar
        sd60, sd80 = s60 * rng.uniform(0.07, 0.11), s80 * rng.uniform(0.06, 0.1)
        stamp = str(start.astype("datetime64[s]")).replace("T", " ")
        out.append(f"{stamp},{s80:.3f},{sd80:.3f},{s60:.3f},{sd60:.3f}")
    path.write_text("\n".join(out) + "\n", encoding="utf-8")


#: The sample bench unit (sample_data/bench): the firmware-2.x example is a campaign of this lidar.
SAMPLE_UNIT = "WLS866-0195"


def firmware2(path: Path, rng: np.random.Generator, n: int = 144) -> None:
    r"""Firmware 2.x newer dialect for the sample unit: ``NA`` internal parameters, one day of periods.

    The header states no internal parameter (``ScanAngle (°)=NA``, ``Pulses / Line of Sight=NA``
    ...), as firmware 2.x writes them; the altitudes follow a tab (``Altitudes (m)=\t40\t60 ...``).
    The columns: ``Timestamp (end of interval)``, the station's environmental columns, then per
    height the eleven quantities and an empty column.  180 m is a height the sample certificate
    does not certify.
    """
    z = np.array([40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0])
    end = np.datetime64("2024-06-01T00:10") + np.arange(n) * PERIOD
    log_u = np.zeros(n)  # AR(1) in log speed about 8 m/s at 80 m: a day of 4-16 m/s, never negative
    for t in range(1, n):
        log_u[t] = 0.97 * log_u[t - 1] + rng.normal(0.0, 0.08)
    u80 = 8.0 * np.exp(log_u + 0.15 * np.sin(2 * np.pi * np.arange(n) / n))
    alpha = np.clip(0.2 + rng.normal(0.0, 0.05, n), 0.02, 0.45)
    speed = u80[:, None] * (z / 80.0) ** alpha[:, None]
    direction = np.mod(225.0 + np.cumsum(rng.normal(0, 2.5, n))[:, None] + 2.0 * np.log(z / 40.0), 360.0)
    cnr = -10.0 - 0.06 * (z - 40.0)[None, :] + rng.normal(0.0, 0.6, speed.shape)
    v = {"speed": speed, "disp": speed * rng.uniform(0.05, 0.16, speed.shape), "dir": direction, "cnr": cnr,
         "avail": np.full(speed.shape, 100.0)}
    v["avail"][:, -2:] = np.round(rng.uniform(75, 100, (n, 2)), 2)
    header = [
        "Version=2.1.0-example",
        f"ID System={SAMPLE_UNIT}",
        "ID Client=Example client (synthetic)",
        "Location=Example campaign site (synthetic)",
        "GPS Location=Lat:53.100000°N, Long:8.300000°E",
        "Comments=synthetic example of the firmware 2.x format, not a measurement",
        "Timezone=UTC+00:00",
        "Installation height (m)=0",
        "****************************************",
        "Configuration",
        "Pulse Repetition Rate (Hz)=NA",
        "Pulses / Line of Sight=NA",
        "Wavelength (nm)=NA",
        "Sampling Frequency (MHz)=NA",
        "FFT Window Width=NA",
        "ScanAngle (°)=NA",
        "DirectionOffset (°)=0",
        "CNRThreshold=-22",
        "Altitudes (m)=\t" + "\t".join(f"{h:g}" for h in z),
        "****************************************",
    ]
    quantities = ["Wind Speed (m/s)", "Wind Speed Dispersion (m/s)", "Wind Speed min (m/s)",
                  "Wind Speed max (m/s)", "Wind Direction (°)", "Z-wind (m/s)", "Z-wind Dispersion (m/s)",
                  "CNR (dB)", "CNR min (dB)", "Dopp Spect Broad (m/s)", "Data Availability (%)"]
    names = ["Timestamp (end of interval)", "Int Temp (°C)", "Ext Temp (°C)", "Pressure (hPa)",
             "Rel Humidity (%)", "Wiper count", "Vbatt (V)"]
    for h in z:
        names += [f"{h:g}m {q}" for q in quantities] + [""]
    lines = [f"HeaderSize={len(header)}", *header, "\t".join(names)]
    for t in range(n):
        stamp = str(end[t].astype("datetime64[m]")).replace("-", "/").replace("T", " ")
        cells = [stamp, f"{24.0 + 2 * np.sin(t / 23):.1f}", f"{14.0 + 3 * np.sin(t / 23):.1f}", "1009.8",
                 f"{70 + 10 * np.cos(t / 31):.1f}", "0", "24.0"]
        for k in range(z.size):
            s, d, c = v["speed"][t, k], v["disp"][t, k], v["cnr"][t, k]
            cells += [cell(s, ".2f"), cell(d, ".2f"), cell(s - 2.2 * d, ".2f"), cell(s + 2.4 * d, ".2f"),
                      cell(v["dir"][t, k], ".1f"), cell(0.02 * s - 0.1, ".2f"), cell(0.4 * d, ".2f"),
                      cell(c, ".1f"), cell(c - 4.0, ".1f"), cell(1.9 + 0 * s, ".2f"),
                      avail_cell(v["avail"][t, k]), ""]
        lines.append("\t".join(cells))
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))


def main() -> None:
    """Write the four example files next to this script (deterministic)."""
    argparse.ArgumentParser(description=__doc__).parse_args()
    ss = np.random.SeedSequence(SEED)
    r1, r2, r3, r4 = (np.random.default_rng(s) for s in ss.spawn(4))
    newer(HERE / "example_newer.sta", r1)
    rows = older(HERE / "example_older.sta", r2)
    mast(HERE / "example_mast.csv", rows, r3)
    firmware2(HERE / "example_firmware2.sta", r4)
    print(f"wrote {HERE}/example_newer.sta, example_older.sta, example_mast.csv, example_firmware2.sta")


if __name__ == "__main__":
    main()
