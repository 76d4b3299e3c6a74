"""Within-laboratory repeatability of bench runs (ISO 5725-4; paper §2.4, Figure 4).

Several operators calibrate the same lidar on the same bench.  Per ℓcv-bin, over the runs
``i``: the grand means of δ_i (``los_bias``) and s_i (``los_std``) and their between-run
standard deviations s_δ and s_s (ddof=1).  A bin enters only when *every* run has more than
``min_samples`` (144) samples in it — the paper says "more than 144" and, a sentence later,
"at least 144"; we take the stricter "more than".  s̄_δ and s̄_s are the means of s_δ and
s_s over the eligible bins inside the window −18 dB … −12 dB, all five LOS and −18 … 18 m/s.

Window bounds are *inclusive* by default.  The paper writes "−18 dB < CNR < −12 dB" and
"−18 m/s < v < 18 m/s" with the same strict signs; read strictly, the velocity condition
would drop the two end points of the −18 … 18 m/s sweep that, in the same sentence, is said
to "cover the typical … wind speed conditions", so the signs denote the ranges of the sweep
(Table 1 writes the same range "−18 m/s to 18 m/s").  Applying one reading to both,
the CNR window holds the −18, −16, −14 and −12 dB bins; ``inclusive=False`` (CLI
``--exclusive``) gives the strict reading (−16 and −14 dB, −17 … 17 m/s).

A run is excluded by its ``run_id`` or ``operator`` attribute (the paper drops operator C's
run 3 for a mis-mounted optical head).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.bench import kernels
from lidarcal.bench.ingest import cube_template
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs, validate_dataset
from lidarcal.units import to_magnitude

__all__ = ["repeatability", "select_runs"]


def _label(ds: xr.Dataset) -> str:
    return (f"run_id={read_attr(ds, 'run_id', kind='bench_cube')!s} "
            f"(operator {read_attr(ds, 'operator', kind='bench_cube')!s})")


def select_runs(cubes: Sequence[xr.Dataset], exclude: Sequence[str] = ()) -> tuple[list, list]:
    """Split ``cubes`` into (kept, excluded) by ``run_id``/``operator`` names in ``exclude``.

    An entry is ``run_id=X``, ``operator=Y`` or a bare name matching either attribute;
    an entry that matches no run raises :class:`InputError`.
    """
    drop = set()
    for entry in exclude:
        key, _, value = entry.partition("=") if "=" in entry else ("", "", entry)
        if key not in ("", "run_id", "operator"):
            raise InputError(f"--exclude {entry!r}: expected RUN_ID, run_id=RUN_ID or operator=NAME")
        hits = [i for i, ds in enumerate(cubes)
                if (key in ("", "run_id") and read_attr(ds, "run_id", kind="bench_cube") == value)
                or (key in ("", "operator") and read_attr(ds, "operator", kind="bench_cube") == value)]
        if not hits:
            raise InputError(f"--exclude {entry!r} matches no run; runs are "
                             f"{[_label(ds) for ds in cubes]}")
        drop.update(hits)
    kept = [ds for i, ds in enumerate(cubes) if i not in drop]
    return kept, [ds for i, ds in enumerate(cubes) if i in drop]


def _check_consistent(cubes: list[xr.Dataset], sources: list[str]) -> None:
    ref = cubes[0]
    for ds, src in zip(cubes[1:], sources[1:], strict=True):
        for attr in ("lidar_serial", "bench_id"):
            if ds.attrs.get(attr) != ref.attrs.get(attr):
                raise InputError(f"{src}: {attr} is {ds.attrs.get(attr)!r} but {sources[0]} has "
                                 f"{ref.attrs.get(attr)!r}; within-laboratory repeatability needs the same "
                                 f"lidar on the same bench")
        for coord in ("los", "cnr", "velocity"):
            if not np.array_equal(ds[coord].values, ref[coord].values):
                raise InputError(f"{src}: coordinate {coord!r} differs from {sources[0]}; expected the same "
                                 f"ℓcv grid in every run")
    ids = [read_attr(ds, "run_id", kind="bench_cube") for ds in cubes]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise InputError(f"run_id(s) {dup} appear in more than one input cube ({sources}); each run once")


def repeatability(
    cubes: Sequence[str | os.PathLike | xr.Dataset],
    *,
    exclude: Sequence[str] = (),
    min_samples: int = 144,
    cnr_window: tuple[float, float] = (-18.0, -12.0),
    velocity_window: tuple[Any, Any] = ("-18 m s-1", "18 m s-1"),
    inclusive: bool = True,
    call: str | None = None,
) -> xr.Dataset:
    """Between-run analysis of several ``bench_cube`` artefacts; returns a ``repeatability`` Dataset.

    Parameters
    ----------
    cubes : paths or Datasets
        One ``bench_cube`` per run of the same lidar on the same bench.
    exclude : names
        Runs to leave out (``run_id`` or ``operator`` values; see :func:`select_runs`).
    min_samples : int
        A bin is used only when every run has more than this many samples in it.
    cnr_window : (float, float)
        CNR window in dB for the summary means.
    velocity_window : (quantity, quantity)
        Velocity window for the summary means.
    inclusive : bool
        Whether the window bounds are included (see the module docstring).
    """
    datasets, sources = [], []
    for item in cubes:
        ds = item if isinstance(item, xr.Dataset) else open_artefact(item, "bench_cube")
        src = source_name(item)
        validate_dataset(ds, "bench_cube", source=src, raise_on_error=True)
        datasets.append(ds)
        sources.append(src)
    kept, dropped = select_runs(datasets, exclude)
    kept_src = [s for ds, s in zip(datasets, sources, strict=True) if any(ds is k for k in kept)]
    if len(kept) < 2:
        raise InputError(f"repeatability needs at least two runs after exclusion; have "
                         f"{[_label(ds) for ds in kept]} (excluded {[_label(ds) for ds in dropped]})")
    _check_consistent(kept, kept_src)
    vlo, vhi = (float(to_magnitude(v, "m s-1", name="velocity_window")) for v in velocity_window)
    clo, chi = (float(c) for c in cnr_window)

    bias = np.stack([ds.los_bias.values for ds in kept])
    std = np.stack([ds.los_std.values for ds in kept])
    count = np.stack([ds.sample_count.values for ds in kept])
    stats = kernels.between_run_stats(bias, std, count, min_samples=min_samples)
    cnr, vel = kept[0].cnr.values, kept[0].velocity.values
    if inclusive:
        in_c, in_v = (cnr >= clo) & (cnr <= chi), (vel >= vlo) & (vel <= vhi)
    else:
        in_c, in_v = (cnr > clo) & (cnr < chi), (vel > vlo) & (vel < vhi)
    used = stats["eligible"] & in_c[None, :, None] & in_v[None, None, :]
    if not used.any():
        raise InputError(
            f"no ℓcv-bin inside CNR {clo:g}…{chi:g} dB, velocity {vlo:g}…{vhi:g} m/s has more than "
            f"{min_samples} samples in every run ({', '.join(kept_src)}); the runs are too short for the "
            f"paper's criterion (lower --min-samples to analyse them anyway)")

    dims = ("los", "cnr", "velocity")
    rdims = ("run", *dims)
    out = cube_template().assign_coords(
        run=("run", np.asarray([read_attr(ds, "run_id", kind="bench_cube") for ds in kept], dtype=object),
             output_attrs("repeatability", "run")),
        operator=("run", np.asarray([read_attr(ds, "operator", kind="bench_cube") for ds in kept],
                                    dtype=object),
                  output_attrs("repeatability", "operator")),
    )
    values = {"run_los_bias": (rdims, bias), "run_los_std": (rdims, std),
              "run_sample_count": (rdims, count.astype(np.int32)),
              **{name: (dims, stats[name]) for name in ("grand_mean_bias", "grand_mean_std",
                                                        "between_run_std_bias", "between_run_std_std")},
              "bin_used": (dims, used.astype(np.int8))}
    s_delta = float(np.mean(stats["between_run_std_bias"][used]))
    s_s = float(np.mean(stats["between_run_std_std"][used]))
    values.update({"mean_between_run_std_bias": ((), s_delta), "mean_between_run_std_std": ((), s_s),
                   "n_runs": ((), np.int32(len(kept))), "n_bins_used": ((), np.int32(used.sum()))})
    for name, (var_dims, data) in values.items():
        out[name] = (var_dims, data, output_attrs("repeatability", name))
    out.attrs.update({
        "lidar_serial": read_attr(kept[0], "lidar_serial", kind="bench_cube"),
        "bench_id": read_attr(kept[0], "bench_id", kind="bench_cube"),
        "runs_used": ", ".join(_label(ds) for ds in kept),
        "runs_excluded": ", ".join(_label(ds) for ds in dropped) or "none",
        "min_samples_exclusive": int(min_samples),
        "cnr_window": f"{clo:g} dB to {chi:g} dB", "velocity_window": f"{vlo:g} m s-1 to {vhi:g} m s-1",
        "window_bounds": "inclusive" if inclusive else "exclusive",
        "time_coverage_start": min(str(ds.attrs["time_coverage_start"]) for ds in kept),
        "time_coverage_end": max(str(ds.attrs["time_coverage_end"]) for ds in kept),
    })
    config = {"exclude": list(exclude), "min_samples": int(min_samples), "cnr_window_dB": [clo, chi],
              "velocity_window_m_s": [vlo, vhi], "inclusive": inclusive}
    roles = {f"cube_run_{read_attr(ds, 'run_id', kind='bench_cube')}": ds for ds in kept}
    roles.update({f"excluded_cube_run_{read_attr(ds, 'run_id', kind='bench_cube')}": ds for ds in dropped})
    return stamp(
        out, "repeatability",
        title=("SAFO-MV within-laboratory repeatability, lidar "
               f"{read_attr(out, 'lidar_serial', kind='bench_cube')}"),
        summary=(f"ISO 5725-4 within-laboratory analysis of {len(kept)} bench runs (paper section 2.4): per "
                 f"ℓcv-bin grand means and between-run standard deviations of the LOS bias and std; "
                 f"s-bar_delta = {s_delta:.4f} m/s and s-bar_s = {s_s:.4f} m/s over {int(used.sum())} bins."),
        call=call or "lidarcal.bench.repeatability(...)",
        input_datasets=roles, config=config,
    )
