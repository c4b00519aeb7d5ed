"""A design page opened in a real headless Chromium (Debian's package; ``.ci/run`` installs it).

What is checked, concretely:

- the scene rendered: the screenshot is not blank, and outside the overlay box (left) it has
  pixels of the robot's orange (the base and the feasible poses) and of the infeasible red (the
  page opens at the pose with the smallest clearance, here an infeasible one);
- the page loads nothing from the network: Chromium writes a NetLog (``--log-net-log``) of every
  URL request; requests the page starts carry the page's origin as initiator (``null`` for a
  file), the browser's own background requests carry none (``not an origin``). No page request
  may use http(s) or ws(s). A control page with an ``<img>`` and a ``fetch`` of TEST-NET
  addresses shows that such requests are seen. All traffic goes to a refused proxy
  (127.0.0.1:9), so nothing leaves the machine either way.
"""

import base64
import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import rgb_to_hsv
from matplotlib.image import imread

from kpioed_drake.robot.models import load_cell, load_robot
from kpioed_drake.scene3d import design_page, write_page
from kpioed_drake.tracker.feasibility import FeasibilityChecker

CHROMIUM = Path("/usr/bin/chromium")
pytestmark = pytest.mark.skipif(
    not CHROMIUM.exists(),
    reason="needs Chromium at /usr/bin/chromium (apt-get install chromium; .ci/run does)",
)
WIDTH, HEIGHT = 1024, 700
ATTEMPTS = 3  # fresh Chromium starts (own profile) when one hangs
OVERLAY_PX = 420  # the overlay box (title, key) is at most this wide, on the left


def _command(page: Path, png: Path, netlog: Path, profile: Path) -> list[str]:
    """The headless Chromium command that screenshots ``page`` and logs its network requests."""
    return [
        str(CHROMIUM),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--use-angle=swiftshader",  # software WebGL
        "--enable-unsafe-swiftshader",
        # Without it a page whose animation plays hangs about every second start (4 of 8 here);
        # with it 20 of 20 finished, 12 of them beside two busy cores.
        "--run-all-compositor-stages-before-draw",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--proxy-server=http://127.0.0.1:9",
        "--proxy-bypass-list=<-loopback>",
        f"--user-data-dir={profile}",
        f"--log-net-log={netlog}",
        f"--screenshot={png}",
        f"--window-size={WIDTH},{HEIGHT}",
        "--virtual-time-budget=8000",
        page.resolve().as_uri(),
    ]


def open_in_chromium(page: Path, tmp: Path) -> tuple[np.ndarray, list[str]]:
    """Screenshot (HEIGHT, WIDTH, 3) in [0, 1] and the http(s)/ws(s) URLs the page requested."""
    for attempt in range(ATTEMPTS):  # headless Chromium can hang on a loaded machine: start it afresh
        png, netlog = tmp / f"{page.stem}-{attempt}.png", tmp / f"{page.stem}-{attempt}-netlog.json"
        try:
            subprocess.run(_command(page, png, netlog, tmp / f"profile-{page.stem}-{attempt}"),
                           capture_output=True, timeout=45, check=False)  # fmt: skip
            break
        except subprocess.TimeoutExpired:
            continue
    assert png.is_file(), "Chromium wrote no screenshot"
    log = json.loads(netlog.read_text())
    start = log["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    requested = []
    for event in log["events"]:
        params = event.get("params", {})
        if event["type"] == start and "url" in params and params.get("initiator") != "not an origin":
            if params["url"].split(":", 1)[0] in ("http", "https", "ws", "wss"):
                requested.append(params["url"])
    return imread(png)[..., :3], requested


def hue_pixels(img: np.ndarray, lo: float, hi: float) -> int:
    """Number of saturated, not dark pixels whose hue (0..1) lies in [lo, hi] (wrapping past 1)."""
    hsv = rgb_to_hsv(img)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    in_hue = (h >= lo) & (h <= hi) if lo <= hi else (h >= lo) | (h <= hi)
    return int(np.sum(in_hue & (s > 0.6) & (v > 0.25)))


@pytest.fixture(scope="module")
def kr16_poses():
    robot = load_robot("kr16")
    cell = load_cell(robot=robot)
    q_bad = robot.q_work.copy()
    q_bad[1] += 1.2
    q = np.array([robot.q_work, robot.q_work + [0.2, -0.1, 0.05, 0.0, 0.0, 0.5], q_bad])
    reports = FeasibilityChecker(robot, cell).check(q)
    assert [r.feasible for r in reports] == [True, True, False]
    return robot, cell, q, reports


@pytest.fixture(scope="module")
def rendered(kr16_poses, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser")
    robot, cell, q, reports = kr16_poses
    page = write_page(tmp / "design.html", design_page(robot, cell, q, reports=reports, Cs=np.eye(3) * 0.03))
    return open_in_chromium(page, tmp)


def test_scene_rendered(rendered):
    img, _ = rendered
    assert img.shape == (HEIGHT, WIDTH, 3)
    scene = img[30:, OVERLAY_PX:]  # without the overlay box and the "Open Controls" bar
    assert scene.std() > 0.05, "blank screenshot"
    assert len(np.unique((scene * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 200
    orange = hue_pixels(scene, 0.04, 0.11)  # ROBOT = (1, 0.42, 0): hue 0.07
    red = hue_pixels(scene, 0.96, 0.02)  # INFEASIBLE = (0.85, 0, 0.1): hue 0.98
    assert orange > 300, f"robot colour: {orange} pixels"
    assert red > 300, f"infeasible colour: {red} pixels"


def test_page_requests_nothing_from_the_network(rendered):
    _, requested = rendered
    assert requested == []


def test_request_check_sees_network_loads(tmp_path):
    page = tmp_path / "control.html"
    page.write_text(
        '<html><body><img src="http://192.0.2.1/x.png">'
        '<script>fetch("https://192.0.2.2/y.json").catch(() => 0)</script>control</body></html>'
    )
    _, requested = open_in_chromium(page, tmp_path)
    assert set(requested) == {"http://192.0.2.1/x.png", "https://192.0.2.2/y.json"}


@pytest.mark.slow
def test_animation_steps_to_another_pose(kr16_poses, tmp_path):
    """The page opens paused at the pose with the smallest clearance (pose 3 here); with the
    animation set to play once, the browser ends on the last frame: pose 2 of a two-pose page."""
    msgpack = pytest.importorskip("msgpack")
    robot, cell, q, reports = kr16_poses
    q2 = q[[2, 1]]  # pose 1 (infeasible) is shown when the page opens; the last frame is pose 2
    page = design_page(robot, cell, q2, reports=FeasibilityChecker(robot, cell).check(q2))

    def play_once(match):
        cmd = msgpack.unpackb(base64.b64decode(match.group(1)), strict_map_key=False)
        if cmd["type"] == "set_animation":
            cmd["options"].update(play=True, repetitions=1, clampWhenFinished=True)
        return (
            f'fetch("data:application/octet-binary;base64,{base64.b64encode(msgpack.packb(cmd)).decode()}")'
        )

    playing = re.sub(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)', play_once, page)
    assert playing != page
    paused_img, _ = open_in_chromium(write_page(tmp_path / "paused.html", page), tmp_path)
    played_img, _ = open_in_chromium(write_page(tmp_path / "played.html", playing), tmp_path)
    region = (slice(30, None), slice(OVERLAY_PX, None))
    red_paused = hue_pixels(paused_img[region], 0.96, 0.02)  # the infeasible pose 1
    red_played = hue_pixels(played_img[region], 0.96, 0.02)  # pose 2 is feasible
    # What stays red: the tracker's x axis and pose 1's reflector point in the overview.
    assert red_paused > 300
    assert red_played < 0.2 * red_paused, (red_paused, red_played)
