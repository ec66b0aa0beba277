"""The results page: relative links and nothing from the network; in headless Chromium every video plays."""

from __future__ import annotations

import functools
import http.server
import json
import re
import shutil
import subprocess
import threading
from html.parser import HTMLParser
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from apf_physics import world_from_dict
from apf_physics.errors import UserError
from apf_physics.experiments.evaluate import evaluate
from apf_physics.planners import make_planner
from apf_physics.render import write_video
from apf_physics.render.page import PAGE, Section, Video, write_page, write_results

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage")

# Loads a page in a frame (same origin), waits until every <video> has its first frame or
# fails, then writes their states into <pre id="result"> for --dump-dom to print.
HARNESS = """<!DOCTYPE html>
<html><body><pre id="result">pending</pre>
<iframe id="page" src="PAGE_URL" width="1200" height="900"></iframe>
<script>
const frame = document.getElementById("page");
frame.addEventListener("load", () => {
  const videos = [...frame.contentDocument.querySelectorAll("video")];
  const settled = video => video.readyState >= 2 || video.error ? Promise.resolve() : new Promise(done => {
    video.addEventListener("loadeddata", done, {once: true});
    video.addEventListener("error", done, {once: true});
  });
  Promise.all(videos.map(settled)).then(() => {
    document.getElementById("result").textContent = JSON.stringify(videos.map(video => ({
      src: video.getAttribute("src"), readyState: video.readyState, duration: video.duration,
      width: video.videoWidth, height: video.videoHeight, error: video.error ? video.error.code : null})));
  });
});
</script></body></html>
"""


def small_world():
    return world_from_dict({
        "name": "page-test", "size": [20, 20], "robot_radius": 0.25, "field": "thesis-demo",
        "obstacles": [{"polygon": [[6, 8], [12, 8], [12, 10], [6, 10]]}],
        "targets": [[15, 16]], "starts": [[3, 3], [9, 4], [16, 3]],
    })


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A results page of two planners in one world: (folder, evaluations)."""
    root = tmp_path_factory.mktemp("results")
    world = small_world()
    evaluations = [evaluate(make_planner("gradient"), [world]), evaluate(make_planner("astar"), [world])]
    write_results(root / "page", evaluations, [world], progress=False)
    return root / "page", evaluations


class _Links(HTMLParser):
    """Every tag with its attributes."""

    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


def parse(page: Path) -> list[tuple[str, dict]]:
    parser = _Links()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser.tags


def video_duration(path: Path) -> float:
    with av.open(str(path)) as container:
        return container.duration / av.time_base


def video_size(path: Path) -> tuple[int, int]:
    """(width, height) of a video's frames as its file declares them."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return stream.codec_context.width, stream.codec_context.height


def test_page_links_only_files_in_its_folder(results):
    folder, evaluations = results
    tags = parse(folder / PAGE)
    links = [value for _, attrs in tags for key, value in attrs.items() if key in ("src", "href", "poster")]
    assert links
    for link in links:
        assert "://" not in link and not link.startswith(("/", "//")), link
        assert (folder / link).is_file(), link
    videos = [attrs for tag, attrs in tags if tag == "video"]
    assert len(videos) == len(evaluations)          # one planner, one world: one video each
    for attrs in videos:
        assert {"controls", "muted", "playsinline"} <= attrs.keys() and attrs["src"].endswith(".mp4")
        assert float(attrs["data-duration"]) == pytest.approx(video_duration(folder / attrs["src"]), abs=0.05)
    assert sum(tag == "img" for tag, _ in tags) == len(evaluations)
    text = (folder / PAGE).read_text(encoding="utf-8")
    assert re.search(r"<td>gradient</td><td>page-test</td><td>3</td>", text)
    assert re.search(r"<td>astar</td><td>page-test</td><td>3</td><td>3/3</td>", text)
    assert "<link" not in text and "@import" not in text and "url(" not in text


def test_page_refuses_files_outside_its_folder(tmp_path):
    outside = tmp_path / "outside.mp4"
    write_video([np.zeros((16, 16, 3), np.uint8)] * 2, outside)
    with pytest.raises(UserError, match="not inside the results folder"):
        write_page(tmp_path / "page", "t", [], [Section("s", videos=[Video(outside, "v", 0.2)])])


@pytest.fixture(scope="module")
def chromium():
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium here (Debian: apt-get install chromium; .ci/run installs it where apt is available)")


@pytest.fixture
def server(tmp_path):
    """An HTTP server on 127.0.0.1 for ``tmp_path``: yields the base URL."""
    handler = functools.partial(_QuietHandler, directory=str(tmp_path))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def run_chromium(chromium: str, profile: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args],
                          capture_output=True, text=True, timeout=180)


def video_states(chromium: str, root: Path, base_url: str, page_url: str) -> list[dict]:
    """The states of the <video> elements of ``page_url`` (relative to ``root``) once they settled."""
    (root / "harness.html").write_text(HARNESS.replace("PAGE_URL", page_url), encoding="utf-8")
    result = run_chromium(chromium, root / "profile", "--virtual-time-budget=15000", "--dump-dom",
                          f"{base_url}/harness.html")
    found = re.search(r'<pre id="result">([^<]*)</pre>', result.stdout)
    assert found, f"Chromium printed no page (exit {result.returncode}): {result.stderr[-2000:]}"
    assert found.group(1) != "pending", "the videos neither loaded nor failed within the time budget"
    return json.loads(found.group(1))


def test_every_video_plays_in_chromium_with_its_duration(results, chromium, server, tmp_path):
    folder, _ = results
    shutil.copytree(folder, tmp_path / "page")
    expected = {attrs["src"]: video_duration(folder / attrs["src"])
                for tag, attrs in parse(folder / PAGE) if tag == "video"}
    states = video_states(chromium, tmp_path, server, f"page/{PAGE}")
    assert sorted(state["src"] for state in states) == sorted(expected)
    for state in states:
        assert state["error"] is None, state
        assert state["readyState"] >= 2, state
        assert state["duration"] == pytest.approx(expected[state["src"]], abs=0.2), state
        # the map is 512 pixels wide; the caption band below it adds to the height
        assert (state["width"], state["height"]) == video_size(folder / state["src"]), state
        assert state["width"] == 512 and state["height"] > 512, state


def test_chromium_check_rejects_an_mp4v_video(chromium, server, tmp_path):
    # The check above can fail: browsers do not decode MPEG-4 Part 2, the old default.
    (tmp_path / "old").mkdir()
    write_video([np.full((64, 64, 3), 120, np.uint8)] * 10, tmp_path / "old" / "old.mp4", codec="mp4v")
    write_page(tmp_path / "old", "mp4v", [], [Section("old", videos=[Video(tmp_path / "old" / "old.mp4", "old", 1.0)])])
    (state,) = video_states(chromium, tmp_path, server, f"old/{PAGE}")
    assert state["readyState"] < 2 and state["error"] is not None


def test_chromium_screenshot_of_the_page_is_not_blank(results, chromium, server, tmp_path):
    folder, _ = results
    shutil.copytree(folder, tmp_path / "page")
    shot = tmp_path / "page.png"
    run_chromium(chromium, tmp_path / "profile", "--virtual-time-budget=15000", "--hide-scrollbars",
                 "--window-size=1280,1600", f"--screenshot={shot}", f"{server}/page/{PAGE}")
    image = cv2.imread(str(shot))
    assert image is not None, "Chromium wrote no screenshot"
    assert image.shape == (1600, 1280, 3)
    assert image.std() > 20
    # Text, the table and the field figures: many colours, not a white page.
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 1000


def test_chromium_shows_the_colours_that_were_drawn(chromium, server, tmp_path):
    # The streams' colour tags (BT.601 matrix, limited range, sRGB) match the conversion: the
    # browser's pixels are the drawn ones, for H.264 and for VP9.
    colours = np.array([(30, 90, 235), (255, 210, 0), (225, 25, 25), (120, 40, 150)], np.uint8)
    frame = np.empty((128, 128, 3), np.uint8)
    for i, colour in enumerate(colours):
        frame[64 * (i // 2): 64 * (i // 2 + 1), 64 * (i % 2): 64 * (i % 2 + 1)] = colour
    write_video([frame] * 10, tmp_path / "quadrants.mp4")
    write_video([frame] * 10, tmp_path / "quadrants.webm")
    (tmp_path / "colours.html").write_text(
        '<html><body style="margin:0"><video src="quadrants.mp4" muted preload="auto" '
        'style="position:absolute;left:0;top:0"></video><video src="quadrants.webm" muted preload="auto" '
        'style="position:absolute;left:200px;top:0"></video></body></html>', encoding="utf-8")
    shot = tmp_path / "colours.png"
    run_chromium(chromium, tmp_path / "profile", "--virtual-time-budget=15000", "--hide-scrollbars",
                 "--window-size=400,200", f"--screenshot={shot}", f"{server}/colours.html")
    image = cv2.imread(str(shot))
    assert image is not None, "Chromium wrote no screenshot"
    for left in (0, 200):
        for i, colour in enumerate(colours):
            shown = image[32 + 64 * (i // 2), left + 32 + 64 * (i % 2), ::-1].astype(int)
            assert np.abs(shown - colour).max() <= 4, (left, colour, shown)
