"""The calibration certificate: one flat, self-verifying netCDF file (paper Figure 1).

:func:`make_certificate` bundles the uncertainty budget, the sensitivities, the bench cube,
the RWF (with Zd), the Table 4 terms and a summary of the records into **one flat Dataset**
that plain netCDF tools (ncdump, netCDF4, any language) read without groups; the full
configuration is a global attribute and each input's provenance (file name, SHA-256, its own
inputs, configuration, seeds and history) the attributes of a scalar variable
``provenance_<role>``.  Writing seals it (:func:`lidarcal.seal.write_certificate`: an integrity
record of every value and attribute, optionally signed with Ed25519; checked by
:func:`lidarcal.seal.verify_certificate`, ``lidarcal verify``).

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
"""

from lidarcal.certificate.build import make_certificate
from lidarcal.certificate.layout import (
    PROVENANCE_PREFIX,
    components,
    container_attributes,
    extract_component,
    open_certificate,
    provenance_chain,
    records_summary,
)
from lidarcal.certificate.measurand import MEASURAND, model_form_summary, model_form_values
from lidarcal.certificate.results import (
    HEADLINE_LABEL,
    certified_rule,
    headline_range,
    headline_sentence,
    headline_text,
    not_settled,
    not_settled_items,
    not_settled_sentence,
    result_table,
)

__all__ = [
    "make_certificate",
    "extract_component",
    "components",
    "container_attributes",
    "provenance_chain",
    "records_summary",
    "open_certificate",
    "PROVENANCE_PREFIX",
    "result_table",
    "headline_range",
    "headline_sentence",
    "headline_text",
    "HEADLINE_LABEL",
    "certified_rule",
    "not_settled",
    "not_settled_sentence",
    "not_settled_items",
    "MEASURAND",
    "model_form_summary",
    "model_form_values",
]
