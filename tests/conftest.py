import logging
import os
import shutil

import pytest

# Simulation kernels are single-threaded by design; oversubscribed BLAS threads on a
# 2-core machine are 10-100x slower (docs/performance.md).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


@pytest.fixture
def chromium() -> tuple[str, str]:
    """Paths of Debian's ``chromium`` and ``chromedriver`` for the browser tests.

    Without them the test is skipped on a developer machine, but fails under ``CI=true``: a CI
    run must not pass by silently skipping the only check that the HTML reports render.
    """
    browser, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if browser is None or driver is None:
        missing = " and ".join(n for n, p in (("chromium", browser), ("chromedriver", driver)) if p is None)
        message = f"{missing} not found (apt-get install chromium chromium-driver; .ci/run does it)"
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI=true and {message}")
        pytest.skip(message)
    return browser, driver


@pytest.fixture
def poppler() -> tuple[str, str]:
    """Paths of poppler-utils' ``pdftoppm`` and ``pdftotext`` for the certificate-document tests.

    Skipped on a developer machine without them, failed under ``CI=true`` (as :func:`chromium`).
    """
    ppm, text = shutil.which("pdftoppm"), shutil.which("pdftotext")
    if ppm is None or text is None:
        message = "pdftoppm/pdftotext not found (apt-get install poppler-utils; .ci/run does it)"
        if os.environ.get("CI") == "true":
            pytest.fail(f"CI=true and {message}")
        pytest.skip(message)
    return ppm, text


#: What only the user knows, given to the shared short calibration (:func:`short_calibration`):
#: contacts, the site (decimal degrees) and further ACDD attributes (tests/test_artefact_metadata.py
#: checks that every artefact carries them).
CONTACT = ["--creator", "A. Steward", "--creator-email", "steward@example.org", "--institution", "Test Lab",
           "--publisher", "Test Archive", "--publisher-email", "archive@example.org",
           "--publisher-url", "https://archive.example.org", "--creator-url", "https://lab.example.org"]
SITE = ["--site-latitude", "55.6869", "--site-longitude", "12.0976"]
USER = [f"--attribute={a}" for a in (
    "contributor_name=B. Analyst", "contributor_role=processor", "program=Test programme",
    "metadata_link=https://archive.example.org/lidar", "acknowledgment=Funded by a test grant",
    "keywords_vocabulary=free text", "platform_vocabulary=free text", "instrument_vocabulary=free text",
    "geospatial_bounds_vertical_crs=height above ground level")]
#: The short calibration's options (tests/test_pipeline.py resumes a killed run of the same ones)
SHORT_RUN = ["--periods", "48", "--min-periods", "3", "--heights", "60", "120", "--workers", "1",
             "--chunk", "16", "--max-replicas", "3", "--no-progress"]


class _Lines(logging.Handler):
    """Collect the messages of the ``lidarcal.pipeline`` logger (caplog is function-scoped)."""

    def __init__(self):
        super().__init__(level=logging.INFO)
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


@pytest.fixture(scope="session")
def short_calibration(tmp_path_factory):
    """One real ``lidarcal calibrate`` of 48 periods at 60 and 120 m, shared by the test files.

    ``(output directory, the CalibrationResult that lidarcal.calibrate returned to the command,
    the lidarcal.pipeline log lines)``.  A calibration this short still takes about a minute on
    2 cores (the model-form alternatives and 3 replicas); test_pipeline.py and
    test_artefact_metadata.py each ran their own until they shared this one.  Read-only: a test
    that writes into the run copies it first.
    """
    import lidarcal.cli.calibrate as command
    from lidarcal.cli import main

    out = tmp_path_factory.mktemp("short-calibration") / "run"
    handler, returned = _Lines(), []
    real = command.calibrate

    def calibrate(*args, **kwargs):  # the command's own call, its result kept for the tests
        returned.append(real(*args, **kwargs))
        return returned[-1]

    logger = logging.getLogger("lidarcal.pipeline")
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(command, "calibrate", calibrate)
            code = main(["calibrate", *SHORT_RUN, "-o", str(out), *CONTACT, *SITE, *USER])
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    assert code == 0 and len(returned) == 1
    return out, returned[0], handler.lines


#: Test files whose slow tests are statistical campaigns (diagnose's confusion matrices and long
#: campaigns on the independent simulator, compare on it, smc's Monte Carlo route against a real
#: calibration): about an hour together on 2 cores, more than CI's 90 minutes leave beside the
#: rest. They are also marked ``campaign``: ``.ci/run`` runs ``-m "slow and not campaign"``; run
#: ``pytest -m campaign`` when you change lidarcal/diagnose, lidarcal/compare, lidarcal/smc or the
#: independent simulator.
CAMPAIGN_FILES = ("test_diagnose_independent.py", "test_diagnose_hidden.py", "test_compare.py",
                  "test_smc_montecarlo.py")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in CAMPAIGN_FILES and item.get_closest_marker("slow"):
            item.add_marker(pytest.mark.campaign)
