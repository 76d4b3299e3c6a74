"""The certificate at work: the uncertainty of the calibrated lidar's wind speed in a campaign (smc).

The paper's §4 c: a specific measurement campaign (SMC), an energy-yield or power-performance
campaign in which the calibrated lidar is deployed, gets per 10-minute period and height the
lidar's wind speed and its combined standard uncertainty, with the contributors apart: the
certificate's certified value (``calibration``), the environmental term by the IEC 61400-50-2
route (``environmental_iec``) and by the Monte Carlo route (``environmental_monte_carlo``), and
the user's own terms.  ``docs/smc.md`` is the method and its sources.

- :func:`smc` (:mod:`.core`) computes it, :func:`smc_dataset` (:mod:`.dataset`) makes the ``smc``
  artefact, :func:`binned` gives its per-bin part with a ``wind_speed`` dimension and
  :func:`binned_table` the table ``lidarcal table`` prints;
- :mod:`.certified` reads what the certificate says (seal first), :mod:`.routes` the calibration
  contributor and the 50-2 route, :mod:`.montecarlo` the Monte Carlo route, :mod:`.user_terms`
  the user's terms, :mod:`.kernels` the numpy kernels, :mod:`.report` the HTML and PDF report.
"""

from lidarcal.smc.core import smc
from lidarcal.smc.dataset import binned, binned_table, smc_dataset

__all__ = ["smc", "smc_dataset", "binned", "binned_table"]
