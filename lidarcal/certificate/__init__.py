"""The certificate wing: the certificate, its seal, its administrative data, its documents.

The calibration certificate is one flat, self-verifying netCDF file (paper Figure 1).

:func:`make_certificate` bundles the uncertainty budget, the sensitivities, the bench cube,
the RWF (with Zd), the Table 4 terms and a summary of the records into **one flat Dataset**
that plain netCDF tools (ncdump, netCDF4, any language) read without groups; the full
configuration is a global attribute and each input's provenance (file name, SHA-256, its own
inputs, configuration, seeds and history) the attributes of a scalar variable
``provenance_<role>``.  Writing seals it (:func:`lidarcal.certificate.seal.write_certificate`:
an integrity record of every value and attribute, optionally signed with Ed25519; checked by
:func:`lidarcal.certificate.seal.verify_certificate`, ``lidarcal verify``).

- :mod:`lidarcal.certificate.build` — :func:`make_certificate`.
- :mod:`lidarcal.certificate.inputs` — the inputs belong together (one lidar, one records chain).
- :mod:`lidarcal.certificate.layout` — the flat layout both ways: :func:`extract_component`,
  :func:`components`, :func:`provenance_chain`, :func:`open_certificate` (a DataTree).
- :mod:`lidarcal.certificate.results` — what it certifies: :func:`headline_range`,
  :func:`headline_sentence` (the one headline builder; :func:`headline_text` as documents show
  it), :func:`not_settled_sentence` and :func:`not_settled_items` (the one wording of what did
  not settle), :func:`result_table` (``lidarcal table``).
- :mod:`lidarcal.certificate.measurand` — what U is (:data:`MEASURAND`) and the model-form term
  in words (:func:`model_form_summary`).
- :mod:`lidarcal.certificate.admin` — the administrative data (``--admin``, issuer, status:
  demonstration or issued); :mod:`lidarcal.certificate.signing` — Ed25519 keys and signatures;
  :mod:`lidarcal.certificate.seal` — writing, sealing and verifying (``lidarcal verify``).
- :mod:`lidarcal.certificate.dcc` — the Digital Calibration Certificate (PTB DCC XML): ``export``,
  ``xml``, ``sign``.
- :mod:`lidarcal.certificate.document` — the PDF; :mod:`lidarcal.certificate.report` — the HTML
  report.

The names below are imported on first access (PEP 562), so that reading a seal
(:mod:`lidarcal.certificate.seal`, ``lidarcal verify``) imports neither the budget's analysis nor
the documents' plotting.
"""

from __future__ import annotations

from importlib import import_module as _import_module
from typing import TYPE_CHECKING

#: Public name -> the submodule that defines it; resolved by :func:`__getattr__` on first access.
_EXPORTS = {
    "make_certificate": "build",
    "PROVENANCE_PREFIX": "layout",
    "components": "layout",
    "container_attributes": "layout",
    "extract_component": "layout",
    "open_certificate": "layout",
    "provenance_chain": "layout",
    "records_summary": "layout",
    "MEASURAND": "measurand",
    "model_form_summary": "measurand",
    "model_form_values": "measurand",
    "HEADLINE_LABEL": "results",
    "certified_rule": "results",
    "headline_range": "results",
    "headline_sentence": "results",
    "headline_text": "results",
    "not_settled": "results",
    "not_settled_items": "results",
    "not_settled_sentence": "results",
    "result_table": "results",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    """Import a public name from its submodule on first access (PEP 562)."""
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'lidarcal.certificate' has no attribute {name!r}") from None
    return getattr(_import_module(f"lidarcal.certificate.{module}"), name)


def __dir__() -> list[str]:
    """List the module's names and the public names not yet imported (PEP 562)."""
    return sorted({*globals(), *_EXPORTS})


if TYPE_CHECKING:  # what type checkers see; at run time __getattr__ imports these
    from lidarcal.certificate.build import (
        make_certificate as make_certificate,
    )
    from lidarcal.certificate.layout import (
        PROVENANCE_PREFIX as PROVENANCE_PREFIX,
    )
    from lidarcal.certificate.layout import (
        components as components,
    )
    from lidarcal.certificate.layout import (
        container_attributes as container_attributes,
    )
    from lidarcal.certificate.layout import (
        extract_component as extract_component,
    )
    from lidarcal.certificate.layout import (
        open_certificate as open_certificate,
    )
    from lidarcal.certificate.layout import (
        provenance_chain as provenance_chain,
    )
    from lidarcal.certificate.layout import (
        records_summary as records_summary,
    )
    from lidarcal.certificate.measurand import (
        MEASURAND as MEASURAND,
    )
    from lidarcal.certificate.measurand import (
        model_form_summary as model_form_summary,
    )
    from lidarcal.certificate.measurand import (
        model_form_values as model_form_values,
    )
    from lidarcal.certificate.results import (
        HEADLINE_LABEL as HEADLINE_LABEL,
    )
    from lidarcal.certificate.results import (
        certified_rule as certified_rule,
    )
    from lidarcal.certificate.results import (
        headline_range as headline_range,
    )
    from lidarcal.certificate.results import (
        headline_sentence as headline_sentence,
    )
    from lidarcal.certificate.results import (
        headline_text as headline_text,
    )
    from lidarcal.certificate.results import (
        not_settled as not_settled,
    )
    from lidarcal.certificate.results import (
        not_settled_items as not_settled_items,
    )
    from lidarcal.certificate.results import (
        not_settled_sentence as not_settled_sentence,
    )
    from lidarcal.certificate.results import (
        result_table as result_table,
    )
