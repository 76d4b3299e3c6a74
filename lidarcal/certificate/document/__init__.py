"""The certificate document: a paginated A4 PDF of a calibration certificate (matplotlib only).

:func:`write_document` writes ``report.pdf``: page 1 is the certificate itself (status, issuer,
customer, calibrated item, dates, method, traceability, seal and the certified result under
the headline), then the figures, every bin of the budget and the inputs with their SHA-256.

- :mod:`lidarcal.certificate.document.facts` — what the documents state (page 1's facts, the headline, the
  certified grid) and how numbers and units are written (:func:`fmt`, :func:`units_suffix`,
  :data:`VARIABLE_NAMES`, shared by every report); the HTML report states the same.
- :mod:`lidarcal.certificate.document.figure_data` — each figure's data, prepared once; the HTML report's
  bokeh figures draw the same records.
- :mod:`lidarcal.certificate.document.figures` — the figures' drawings, shared with the HTML report's PNGs.
- :mod:`lidarcal.certificate.document.pages` — the PDF's page layout and :func:`write_document`.
"""

from lidarcal.certificate.document.facts import VARIABLE_NAMES, fmt, seal_statement, units_suffix
from lidarcal.certificate.document.figures import parts_of
from lidarcal.certificate.document.pages import write_document

__all__ = ["write_document", "parts_of", "seal_statement", "fmt", "units_suffix", "VARIABLE_NAMES"]
