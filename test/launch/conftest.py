"""Launch tests run only as launch tests: through the launch_testing pytest plugin.

Where that plugin is not loaded (launch_testing missing, or `-p no:launch_testing`), pytest
would collect these files as plain modules and run their test classes with nothing
launched; they are skipped instead, with a one-line reason. ASLIP_REQUIRE_LAUNCH=1 (CI
with the launch stack) turns that skip into an error, so no launch test is skipped there.
"""

import os
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def _reason(config) -> str:
    from launch_case import MISSING
    if MISSING is not None:
        return MISSING
    if not config.pluginmanager.has_plugin("launch_testing"):
        return "the launch_testing pytest plugin is not loaded"
    return "not marked @pytest.mark.launch_test"


def pytest_collection_modifyitems(config, items):
    mine = [i for i in items if HERE in Path(str(i.path)).resolve().parents
            and type(i).__name__ not in ("LaunchTestItem", "LaunchROSTestItem")]
    if not mine:
        return
    reason = _reason(config)
    if os.environ.get("ASLIP_REQUIRE_LAUNCH") == "1":
        raise pytest.UsageError(f"launch tests required but not runnable: {reason}")
    for item in mine:
        item.add_marker(pytest.mark.skip(reason=reason))
