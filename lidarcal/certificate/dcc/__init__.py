"""The Digital Calibration Certificate: a sealed certificate as PTB DCC XML (its exchange form).

- :mod:`lidarcal.certificate.dcc.export` — :func:`dcc_tree`, :func:`write_dcc` (``lidarcal dcc``)
  and :func:`validate_dcc` (against PTB's XSDs).
- :mod:`lidarcal.certificate.dcc.xml` — the XML helpers and the administrative part (status,
  statements, the laboratory and the item).
- :mod:`lidarcal.certificate.dcc.sign` — the XAdES-BES signature of a DCC and its check
  (``lidarcal dcc --sign-x509``, ``--verify``); imported only when signing or verifying.
"""

from lidarcal.certificate.dcc.export import (
    COVERAGE_PROBABILITY,
    DCC_NS,
    DCC_SCHEMA_VERSION,
    SI_NS,
    SI_SCHEMA_URL,
    dcc_attributes,
    dcc_tree,
    validate_dcc,
    write_dcc,
)

__all__ = ["DCC_NS", "SI_NS", "DCC_SCHEMA_VERSION", "SI_SCHEMA_URL", "dcc_tree", "write_dcc", "validate_dcc",
           "dcc_attributes", "COVERAGE_PROBABILITY"]
