"""Headless Chromium for the report's browser tests, driven by Playwright (pip ``playwright``;
no browser download: it starts Debian's ``/usr/bin/chromium``).

Locally the tests skip when either is missing; under CI (``CI`` set, as ``.ci/run`` runs) a
missing browser is a failure, so that CI cannot pass without running them.
"""

import contextlib
import os
import shutil
import tempfile

import pytest

__all__ = ["chromium_path", "open_page", "FLAGS"]

#: the machine notes' flags: no sandbox (root), no GPU, and no background traffic to a network
#: that is closed here
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def chromium_path():
    """The Chromium executable; skips (locally) or fails (CI) when it or Playwright is missing."""
    path = os.environ.get("PSRIG_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        path = None
        why = "playwright is not installed (pip install playwright; .ci/run does)"
    else:
        why = "no chromium on this machine (apt-get install chromium; .ci/run does)"
    if path is None:
        if os.environ.get("CI"):
            pytest.fail(f"browser test under CI: {why}")
        pytest.skip(why)
    return path


@contextlib.contextmanager
def open_page(url, viewport=(1200, 900)):
    """A page of a fresh headless Chromium at ``url``; yields (page, problems), ``problems``
    collecting console errors, page errors and failed requests as they come."""
    from playwright.sync_api import sync_playwright

    executable = chromium_path()
    problems = []
    with sync_playwright() as driver, tempfile.TemporaryDirectory(prefix="psrig-chromium-") as profile:
        context = driver.chromium.launch_persistent_context(
            profile, executable_path=executable, headless=True, args=FLAGS,
            viewport={"width": viewport[0], "height": viewport[1]})
        try:
            page = context.new_page()
            page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url} ({r.failure})"))
            page.goto(url)
            yield page, problems
        finally:
            context.close()
