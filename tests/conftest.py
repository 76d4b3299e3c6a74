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
