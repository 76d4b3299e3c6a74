"""What a certificate says that a campaign uncertainty needs, read once and checked before any work.

:func:`read_certified` checks the certificate's seal first (and its signature against
``public_key`` when given: :func:`lidarcal.certificate.seal.require_valid_seal`), then reads its components:
the budget (which bins are certified, read from ``bin_flag``'s ``flag_meanings``, never from
numbers, so that meanings added later, such as ``not_settled``, stay uncertified), the
sensitivities (slopes, their significance and the calibration's distribution of each variable
per height), the Table 4 terms, the bench cube and RWF, and the lidar model the calibration
simulated (``lidarcal_records_summary``), which :meth:`Certified.lidar_model` restores from
the cube and RWF by digest (:meth:`lidarcal.lidar.LidarModel.from_dict`), so the Monte Carlo
route simulates exactly the calibrated lidar.  What an older certificate lacks is named when a
route needs it (:meth:`Certified.require`), never filled in.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.admin import DEMONSTRATION, STATUS_ATTR, STATUS_REASON_ATTR
from lidarcal.certificate.layout import components, extract_component, records_summary
from lidarcal.certificate.seal import require_valid_seal
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, read_image
from lidarcal.lidar import LidarModel
from lidarcal.readback import read_attr

__all__ = ["Certified", "read_certified", "flag_meanings"]


def flag_meanings(var: xr.DataArray) -> dict[int, str]:
    """``{flag value: meaning}`` of a CF flag variable (``flag_values`` / ``flag_meanings``)."""
    values = np.atleast_1d(var.attrs.get("flag_values", []))
    meanings = str(var.attrs.get("flag_meanings", "")).split()
    return {int(v): m for v, m in zip(values, meanings, strict=False)}


@dataclass(frozen=True)
class Certified:
    """The parts of a sealed certificate a campaign uncertainty uses (see the module docstring)."""

    path: Path
    attrs: dict[str, Any]
    budget: xr.Dataset
    sensitivities: dict[str, xr.Dataset]
    terms: xr.Dataset | None
    cube: xr.Dataset | None
    rwf: xr.Dataset | None
    summary: dict[str, Any] | None
    seal: str = "not checked"
    missing: dict[str, str] = field(default_factory=dict)

    @property
    def serial(self) -> str | None:
        """The calibrated item's serial number (``item_serial_number``, else ``lidar_serial``)."""
        return (read_attr(self.attrs, "item_serial_number", kind="certificate")
                or read_attr(self.attrs, "lidar_serial", kind="certificate"))

    @property
    def status(self) -> str:
        """``calibration_status``: ``demonstration`` or ``issued`` (``not stated`` for an old file)."""
        return str(self.attrs.get(STATUS_ATTR, "not stated"))

    @property
    def demonstration(self) -> bool:
        """True for a demonstration certificate: the campaign uncertainty is a demonstration too."""
        return self.status == DEMONSTRATION

    @property
    def status_reason(self) -> str:
        """Why the certificate has its status (empty when it does not say)."""
        return str(self.attrs.get(STATUS_REASON_ATTR, ""))

    @property
    def heights(self) -> np.ndarray:
        """The certified heights (m): the budget's heights."""
        return np.asarray(self.budget["height"].values, dtype=float)

    @property
    def flags(self) -> dict[int, str]:
        """The budget's ``bin_flag`` meanings."""
        return flag_meanings(self.budget["bin_flag"])

    @property
    def certified_flag(self) -> int:
        """The ``bin_flag`` value whose meaning is ``certified``."""
        return next(v for v, m in self.flags.items() if m == "certified")

    @property
    def model_record(self) -> dict[str, Any] | None:
        """The lidar model the calibration simulated (attribute form), if the certificate records it."""
        rec = (self.summary or {}).get("lidarcal_lidar_model")
        return rec if isinstance(rec, dict) else None

    @property
    def cone_angle(self) -> float | None:
        """The calibrated lidar's nominal cone angle (degree from vertical), see :attr:`cone_angle_origin`."""
        rec = self.model_record
        if rec is not None and "cone_angle" in rec:
            return float(rec["cone_angle"])
        if self.terms is not None and "cone_angle" in self.terms:
            found = np.unique(np.asarray(self.terms["cone_angle"].values, dtype=float))
            if found.size == 1 and self.terms["cone_angle"].attrs.get("units") in ("degree", "degrees"):
                return float(found[0])
        return None

    @property
    def cone_angle_origin(self) -> str:
        """Where :attr:`cone_angle` comes from: the lidar model, else the Table 4 terms' cone angle."""
        rec = self.model_record
        if rec is not None and "cone_angle" in rec:
            return f"the certificate's lidar model ({self.path.name})"
        return f"the certificate's Table 4 terms ({self.path.name}, terms_cone_angle)"

    @property
    def hybrid_weight(self) -> float | None:
        """The calibrated lidar's hybrid weight p, from its recorded model."""
        rec = self.model_record
        return None if rec is None or "hybrid_weight" not in rec else float(rec["hybrid_weight"])

    def require(self, what: str, route: str) -> None:
        """Refuse, naming the route and the missing part, when the certificate lacks ``what``."""
        if what in self.missing:
            raise InputError(f"{self.path}: the certificate cannot give the {route}: {self.missing[what]}")

    def lidar_model(self) -> LidarModel:
        """Return the lidar the calibration simulated, its bench noise table and RWF restored and checked."""
        self.require("lidar_model", "Monte Carlo route (the calibrated virtual lidar)")
        source = f"{self.path.name}: global attribute 'lidarcal_records_summary' (lidarcal_lidar_model)"
        return LidarModel.from_dict(self.model_record, cube=self.cube, rwf=self.rwf, source=source)


def _certified_meaning(budget: xr.Dataset, path: Path) -> None:
    found = flag_meanings(budget["bin_flag"]) if "bin_flag" in budget else {}
    if "certified" not in found.values():
        raise InputError(
            f"{path}: variable 'budget_bin_flag': expected a flag meaning 'certified' (flag_meanings); found "
            f"{budget['bin_flag'].attrs.get('flag_meanings') if 'bin_flag' in budget else 'no variable'!r}: "
            "the certificate predates the certification rule, so no bin can be taken as certified"
        )


def read_certified(path: str | os.PathLike, *, public_key: str | os.PathLike | None = None) -> Certified:
    """Check a certificate's seal, then read what a campaign uncertainty needs from it.

    Raises
    ------
    SealError
        The seal (or, with ``public_key``, the signature) does not match the contents, or the
        file was never sealed (or signed).
    InputError
        Not a certificate, or a budget without the ``certified`` meaning.
    """
    path = Path(path)
    # the seal first, before any number is read, on the file's bytes read once; the numbers are
    # read from that same image (lidarcal.io.open_image): exactly the bytes checked
    image = read_image(path, "certificate file")
    report = require_valid_seal(path, public_key=public_key, image=image)
    cert = open_artefact(path, "certificate", image=image)
    if read_attr(cert, "lidarcal_artefact") != "certificate":
        raise InputError(
            f"{path}: not a lidarcal certificate (global attribute 'lidarcal_artefact' is "
            f"{read_attr(cert, 'lidarcal_artefact')!r})"
        )
    names = {c["name"] for c in components(cert)}
    budget = extract_component(cert, "budget").load()
    _certified_meaning(budget, path)
    sens = {}
    for name in sorted(n for n in names if n.startswith("sensitivity_")):
        ds = extract_component(cert, name).load()
        var = read_attr(ds, "environmental_variable", kind="sensitivity", default=name[len("sensitivity_") :])
        sens[var] = ds
    parts = {
        role: extract_component(cert, role).load() if role in names else None
        for role in ("terms", "cube", "rwf")
    }
    for role, ds in parts.items():
        if ds is not None:  # messages about a component name the certificate
            ds.attrs.setdefault("lidarcal_source_file", f"{path.name} ({role} component)")
    summary = records_summary(cert)
    missing: dict[str, str] = {}
    if not sens:
        missing["sensitivities"] = "it carries no sensitivity component (no slope to apply)"
    model = (summary or {}).get("lidarcal_lidar_model")
    if not isinstance(model, dict):
        missing["lidar_model"] = (
            "its global attribute 'lidarcal_records_summary' records no "
            "'lidarcal_lidar_model' (the lidar the calibration simulated)"
        )
    elif parts["cube"] is None and isinstance(model.get("noise_table"), dict):
        missing["lidar_model"] = "it has no bench cube component to restore the lidar's LOS noise from"
    elif parts["rwf"] is None and isinstance(model.get("rwf_profile"), dict):
        missing["lidar_model"] = (
            "it has no rwf component to restore the lidar's range-weighting function from"
        )
    if parts["terms"] is None:
        missing["terms"] = "it has no Table 4 terms component (virtual reference uncertainty)"
    seal = "not checked" if report is None else ("signed and sealed" if report.signed_by else "sealed")
    attrs = {k: v for k, v in cert.attrs.items()}
    return Certified(
        path=path,
        attrs=attrs,
        budget=budget,
        sensitivities=sens,
        terms=parts["terms"],
        cube=parts["cube"],
        rwf=parts["rwf"],
        summary=summary,
        seal=seal,
        missing=missing,
    )
