"""What type checkers see of ``lidarcal``: the entry points ``__init__.py`` imports on first use."""

from lidarcal import units as units
from lidarcal.analysis.budget import budget as budget
from lidarcal.analysis.sensitivity import sensitivity as sensitivity
from lidarcal.campaign import simulate_campaign as simulate_campaign
from lidarcal.certificate import make_certificate as make_certificate
from lidarcal.certificate import open_certificate as open_certificate
from lidarcal.certificate import result_table as result_table
from lidarcal.certificate.seal import verify_certificate as verify
from lidarcal.diagnose import diagnose as diagnose_campaign
from lidarcal.io import open_artefact as open_artefact
from lidarcal.lidar import LidarModel as LidarModel
from lidarcal.pipeline import CalibrationConfig as CalibrationConfig
from lidarcal.pipeline import CalibrationResult as CalibrationResult
from lidarcal.pipeline import calibrate as calibrate

__version__: str

__all__ = [
    "__version__", "calibrate", "CalibrationConfig", "CalibrationResult", "open_artefact", "LidarModel",
    "simulate_campaign", "sensitivity", "budget", "make_certificate", "verify", "open_certificate",
    "result_table", "diagnose_campaign",
]
