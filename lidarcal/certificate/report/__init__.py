"""Offline HTML report of a calibration (interactive bokeh plots) and the certificate document.

- :mod:`lidarcal.certificate.report.plots` — the page's figures (:class:`Figure`, :func:`report_figures`),
  plain bokeh through :mod:`lidarcal.htmlpage`, drawn from :mod:`lidarcal.certificate.document.figure_data`.
- :mod:`lidarcal.certificate.report.page` — :func:`write_report`: the page (status, headline, certified
  result, the certificate's facts, the figures, the inputs), the PDF and the PNGs beside it.
"""

from lidarcal.certificate.report.page import write_report
from lidarcal.certificate.report.plots import Figure, report_figures

__all__ = ["write_report", "report_figures", "Figure"]
