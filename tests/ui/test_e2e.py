"""The operator page end to end: headless Chromium (Debian's, installed by `make setup`)
driven by Playwright, against the real server on a realtime simulation.

Each step is checked on the page and against the simulator's truth. Screenshots go to the
test's temporary folder, or to ``$ARMVISION_UI_SCREENSHOTS`` when set (the README's picture
is made that way).
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, Page, expect, sync_playwright

from .conftest import RunningUI, captured_logs, running_ui

CHROMIUM_ENV = "ARMVISION_CHROMIUM"
# As the machine's notes prescribe for a closed network: no first-run, sync or background
# traffic; --no-sandbox because CI runs as root.
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

# The colour image's pixels as one checksum (the <img> drawn on a canvas).
FRAME_CHECKSUM_JS = """() => {
  const img = document.getElementById('video');
  if (!img.complete || img.naturalWidth === 0) return null;
  const c = document.createElement('canvas');
  c.width = img.naturalWidth; c.height = img.naturalHeight;
  const g = c.getContext('2d');
  g.drawImage(img, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let s = 0;
  for (let i = 0; i < d.length; i += 1) s = (s * 31 + d[i]) % 2147483647;
  return s;
}"""


# A page of another site (another port of this machine) that tries to drive the arm through
# the UI: a plain HTML form (no script needed), a no-cors fetch (what a script may send anywhere
# without asking), a JSON fetch (the browser asks first and the UI does not say yes), a frame.
FOREIGN_PAGE = """<!doctype html>
<html><head><title>another site</title></head><body>
<form id="form" method="POST" enctype="text/plain" action="{ui}/api/actions/home"></form>
<iframe id="frame" src="{ui}/" width="400" height="300"></iframe>
<script>
async function noCorsFetch() {{
  try {{
    const r = await fetch('{ui}/api/actions/home', {{method: 'POST', mode: 'no-cors',
      headers: {{'Content-Type': 'text/plain'}}, body: '{{}}'}});
    return r.type;  // 'opaque': sent, its answer unreadable
  }} catch (err) {{
    return 'sent, answer blocked';  // the UI's Cross-Origin-Resource-Policy
  }}
}}
async function jsonFetch() {{
  try {{
    await fetch('{ui}/api/actions/home', {{method: 'POST',
      headers: {{'Content-Type': 'application/json'}}, body: '{{}}'}});
    return 'answered';
  }} catch (err) {{
    return 'refused';
  }}
}}
</script>
</body></html>
"""


def chromium_path() -> str:
    candidates = [os.environ.get(CHROMIUM_ENV), "/usr/bin/chromium", "/usr/bin/chromium-browser"]
    candidates += [shutil.which("chromium"), shutil.which("chromium-browser")]
    for path in candidates:
        if path and Path(path).exists():
            return path
    pytest.fail(
        "Chromium not found: `make setup` installs Debian's chromium package; elsewhere set "
        f"{CHROMIUM_ENV} to a Chromium or Chrome executable"
    )


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    where = os.environ.get("ARMVISION_UI_SCREENSHOTS")
    path = Path(where) if where else tmp_path_factory.mktemp("screenshots")
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture(scope="module")
def ui() -> Iterator[RunningUI]:
    with running_ui() as running:
        yield running


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def page(browser: Browser, ui: RunningUI) -> Iterator[Page]:
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    page.js_errors = []  # type: ignore[attr-defined]
    page.on("pageerror", lambda exc: page.js_errors.append(str(exc)))  # type: ignore[attr-defined]
    # Anything the page's Content-Security-Policy blocks is reported on the console.
    page.on(
        "console",
        lambda msg: (
            page.js_errors.append(msg.text)  # type: ignore[attr-defined]
            if "Content Security Policy" in msg.text
            else None
        ),
    )
    page.goto(ui.url + "/")
    expect(page.locator("#conn")).to_have_text("live", timeout=10_000)
    yield page
    assert page.js_errors == []  # type: ignore[attr-defined]
    page.close()


@pytest.fixture(scope="module")
def foreign_site(ui: RunningUI) -> Iterator[str]:
    """FOREIGN_PAGE served from another port of 127.0.0.1 (another origin)."""
    body = FOREIGN_PAGE.format(ui=ui.url).encode()

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:  # quiet
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_port}/"
    finally:
        server.shutdown()
        server.server_close()


def _joints_deg(page: Page) -> np.ndarray:
    names = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
    return np.array([float(page.locator(f"#joint-{n}").inner_text()) for n in names])


def _wait(condition, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)


def test_the_video_is_live(page: Page, shots: Path) -> None:
    _wait(lambda: page.evaluate(FRAME_CHECKSUM_JS) is not None, 10, "a first video frame")
    assert page.evaluate("document.getElementById('video').naturalWidth") == 640
    first_index = int(page.locator("#frame-index").inner_text())
    first = page.evaluate(FRAME_CHECKSUM_JS)
    time.sleep(1.0)
    assert page.evaluate(FRAME_CHECKSUM_JS) != first  # new pictures arrive
    assert int(page.locator("#frame-index").inner_text()) > first_index
    expect(page.locator("#mode")).to_have_text("SIM")
    expect(page.locator("#tracks tbody tr")).to_have_count(2)  # the bottle and the cup
    expect(page.locator("#health tbody tr")).to_have_count(6)
    page.locator("#show-depth").check()
    _wait(
        lambda: page.evaluate("document.getElementById('depth').naturalWidth") == 640,
        10,
        "the depth view",
    )
    page.screenshot(path=str(shots / "ui-depth.png"))
    page.locator("#show-depth").uncheck()


def test_home_brings_the_joints_home(page: Page, ui: RunningUI) -> None:
    # The simulated arm starts in its sleep pose.
    assert np.max(np.abs(_joints_deg(page))) > 30
    page.locator("#btn-home").click()
    expect(page.locator("#task-name")).to_have_text("home", timeout=5_000)
    _wait(lambda: np.max(np.abs(_joints_deg(page))) < 1.0, 20, "the page's joints at home")
    expect(page.locator("#task-phase")).to_have_text("succeeded", timeout=5_000)
    assert np.max(np.abs(np.degrees(ui.system.world.joint_positions()))) < 1.0  # truth


def test_a_detector_switches_off_and_on(page: Page, ui: RunningUI) -> None:
    objects = page.locator("#det-objects")
    expect(objects).to_be_checked()
    objects.uncheck()
    _wait(lambda: not ui.system.enabled["objects"], 5, "object detection off")
    row = page.locator('#health tr[data-thread="objects"]')
    expect(row).to_contain_text("off", timeout=5_000)
    time.sleep(0.5)  # a detection under way when the switch went off may still finish
    outputs = ui.system.meters["objects"].health(True, True, 1.0).outputs
    time.sleep(1.0)
    assert ui.system.meters["objects"].health(True, True, 1.0).outputs == outputs
    objects.check()
    _wait(lambda: ui.system.enabled["objects"], 5, "object detection on")
    expect(row).to_contain_text("ok", timeout=10_000)
    assert ui.system.meters["objects"].health(True, True, 1.0).outputs > outputs
    expect(objects).to_be_checked()


def test_record_then_stop_recording(
    page: Page, ui: RunningUI, tmp_path_factory: pytest.TempPathFactory
) -> None:
    import dataclasses

    from armvision.recording.reader import Recording

    app = ui.server.ui
    folder = tmp_path_factory.mktemp("recordings")
    app.config = dataclasses.replace(
        app.config, record=dataclasses.replace(app.config.record, dir=str(folder))
    )
    button = page.locator("#btn-record")
    expect(button).to_have_text("Record")
    button.click()
    expect(button).to_have_text("Stop recording", timeout=5_000)
    expect(page.locator("#record-status")).to_contain_text(str(folder), timeout=5_000)
    time.sleep(1.5)
    button.click()
    expect(button).to_have_text("Record", timeout=10_000)
    expect(page.locator("#record-status")).to_contain_text("recorded")
    (path,) = folder.iterdir()
    frames = [m for m in Recording(path).messages() if m.topic.endswith("image_raw")]
    assert frames  # a finished file (the streaming reader read it to its end)
    assert not Recording(path).truncated


def test_stop_during_a_follow(page: Page, ui: RunningUI) -> None:
    page.locator("#btn-follow-tag").click()
    expect(page.locator("#task-phase")).to_have_text("running", timeout=5_000)
    expect(page.locator("#task-message")).to_contain_text("following", timeout=15_000)
    expect(page.locator("#btn-grab")).to_be_disabled()  # conflicting controls
    expect(page.locator("#btn-stop")).to_be_enabled()
    time.sleep(1.0)
    page.locator("#btn-stop").click()
    expect(page.locator("#task-phase")).to_have_text("stopped", timeout=3_000)
    expect(page.locator("#task-error")).to_have_text("stopped by the operator")
    world = ui.system.world
    q = world.joint_positions()
    time.sleep(0.5)
    assert np.max(np.abs(world.joint_positions() - q)) < 0.02  # the arm holds still
    expect(page.locator("#btn-grab")).to_be_enabled(timeout=3_000)


def test_another_site_cannot_drive_the_arm(
    browser: Browser, page: Page, ui: RunningUI, foreign_site: str
) -> None:
    world = ui.system.world

    def unchanged(task_id: int | None, q: np.ndarray) -> None:
        time.sleep(0.5)  # a task that had started would be moving by now
        assert ui.system.snapshot().task.task_id == task_id  # no task started
        assert np.max(np.abs(world.joint_positions() - q)) < 0.02  # the arm did not move

    task_id, q = ui.system.snapshot().task.task_id, world.joint_positions()
    other = browser.new_page()
    with captured_logs() as logs:
        other.goto(foreign_site)
        with other.expect_navigation() as navigation:
            other.evaluate("document.getElementById('form').submit()")
        assert navigation.value is not None and navigation.value.status == 403
        assert "another site" in other.inner_text("body")
        unchanged(task_id, q)
        other.goto(foreign_site)
        assert other.evaluate("noCorsFetch()") in ("opaque", "sent, answer blocked")
        assert other.evaluate("jsonFetch()") == "refused"  # by the browser: never sent
        unchanged(task_id, q)
        # The UI refuses to be framed: the frame shows the browser's error page instead.
        frame = next(f for f in other.frames if f is not other.main_frame)
        assert frame.url.startswith("chrome-error:"), frame.url
        other.close()
    refused = [r for r in logs.records if "from another site" in r.getMessage()]
    assert len(refused) == 2, [r.getMessage() for r in logs.records]  # the form, the fetch
    # The UI's own page, in the same browser, still drives the arm.
    page.locator("#btn-home").click()
    _wait(lambda: ui.system.snapshot().task.task_id != task_id, 5, "Home to start")
    expect(page.locator("#task-name")).to_have_text("home", timeout=5_000)
    expect(page.locator("#task-phase")).to_have_text("succeeded", timeout=20_000)
    assert np.max(np.abs(np.degrees(world.joint_positions()))) < 1.0  # home, says the simulator


def _in_zone(ui: RunningUI, name: str, zone: str) -> bool:
    x0, y0, x1, y1 = ui.system.config.place.zones[zone]
    x, y = ui.system.world.T_base_object(name)[:2, 3]
    return bool(x0 <= x <= x1 and y0 <= y <= y1)


def _upright(ui: RunningUI, name: str) -> bool:
    return next(o for o in ui.system.world.objects() if o.spec.name == name).upright


def test_stop_during_a_sort_halts_the_arm(page: Page, ui: RunningUI) -> None:
    expect(page.locator("#zone-select option")).to_have_count(2)  # the zones from the state
    page.locator("#btn-sort").click()
    expect(page.locator("#task-phase")).to_have_text("running", timeout=5_000)
    expect(page.locator("#task-message")).to_contain_text("measuring", timeout=30_000)
    expect(page.locator("#btn-place")).to_be_disabled()
    page.locator("#btn-stop").click()
    expect(page.locator("#task-phase")).to_have_text("stopped", timeout=3_000)
    world = ui.system.world
    q = world.joint_positions()
    time.sleep(0.5)
    assert np.max(np.abs(world.joint_positions() - q)) < 0.02  # the arm holds still
    assert world.held_object() is None


def test_sort_runs_to_completion(page: Page, ui: RunningUI, shots: Path) -> None:
    # The bench's bottle is 60 % full: the default rule (below 30 % empty) takes it to "full".
    page.locator("#sort-by").select_option("fill")
    page.locator("#btn-sort").click()
    expect(page.locator("#task-phase")).to_have_text("running", timeout=5_000)
    expect(page.locator("#task-phase")).to_have_text("succeeded", timeout=300_000)
    expect(page.locator("#task-result")).to_contain_text("placed")
    assert _in_zone(ui, "bottle", "full") and _upright(ui, "bottle")
    assert ui.system.world.held_object() is None
    page.screenshot(path=str(shots / "ui-after-sort.png"))


def test_grab_bottle_succeeds(page: Page, ui: RunningUI, shots: Path) -> None:
    world = ui.system.world
    z0 = world.T_base_object("bottle")[2, 3]
    page.locator("#btn-grab").click()
    expect(page.locator("#task-phase")).to_have_text("running", timeout=5_000)
    expect(page.locator("#btn-home")).to_be_disabled()
    # The README's picture: the gripper near the bottle, progress showing.
    _wait(
        lambda: float(page.locator("#task-progress").get_attribute("value") or 0) >= 0.5,
        40,
        "the grab half done",
    )
    page.screenshot(path=str(shots / "ui-grab.png"))
    expect(page.locator("#task-phase")).to_have_text("succeeded", timeout=60_000)
    assert world.held_object() == "bottle"
    assert world.T_base_object("bottle")[2, 3] - z0 > 0.05  # lifted, says the simulator
    expect(page.locator("#task-result")).to_contain_text("track")
    page.screenshot(path=str(shots / "ui-after-grab.png"))
    assert (shots / "ui-grab.png").stat().st_size > 10_000


def test_place_sets_the_held_bottle_down_in_the_chosen_zone(page: Page, ui: RunningUI) -> None:
    assert ui.system.world.held_object() == "bottle"  # from the grab above
    page.locator("#zone-select").select_option("empty")
    page.locator("#btn-place").click()
    expect(page.locator("#task-phase")).to_have_text("running", timeout=5_000)
    expect(page.locator("#task-phase")).to_have_text("succeeded", timeout=120_000)
    assert _in_zone(ui, "bottle", "empty") and _upright(ui, "bottle")
    assert ui.system.world.held_object() is None
