"""rt2 label end to end in a real headless Chromium driven by selenium: load a folder, a video and a session
log; label by keys and by mouse; kill the server mid-way and find every confirmed label on disk; restart,
reload and continue; train and find the model file.

Needs Debian's ``chromium`` and ``chromium-driver`` (/usr/bin) and the ``selenium`` package (the ``test``
extra); `.ci/run` installs them. Skipped, with the reason, where they are missing.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from harness.common.spawn import ReadyProcess
from harness.experiments.detector.coco import read_coco

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--window-size=1400,800")
WAIT_S = 30


@pytest.fixture(scope="module")
def browser():
    if not (CHROMIUM.is_file() and CHROMEDRIVER.is_file()):
        pytest.skip(f"no {CHROMIUM} and {CHROMEDRIVER} (apt-get install chromium chromium-driver): the page's browser tests need them")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install -e '.[test]')")
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="rt2-label-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in FLAGS + (f"--user-data-dir={profile}",):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)  # never selenium-manager
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def start_label(source, out, *extra) -> ReadyProcess:
    return ReadyProcess(["label", str(source), "--out", str(out), "--port", "0", *map(str, extra)], what="rt2 label", timeout_s=180)


class Page:
    """The page as the test sees it: keys, clicks at image pixels, and what it shows."""

    def __init__(self, driver, url):
        from selenium.webdriver.support.ui import WebDriverWait

        self.d = driver
        self.wait = WebDriverWait(driver, WAIT_S, poll_frequency=0.05)
        driver.get(url)
        self.wait.until(lambda d: d.execute_script("return rt2label.frame !== null && !rt2label.busy"))

    def js(self, expr):
        return self.d.execute_script(f"return {expr}")

    @property
    def current(self) -> tuple[int, str]:
        return self.js("rt2label.cur"), self.js("rt2label.frame.key")

    def text(self, element_id) -> str:
        return self.d.find_element("id", element_id).text

    def keys(self, *keys) -> None:
        from selenium.webdriver.common.action_chains import ActionChains

        chain = ActionChains(self.d)
        for k in keys:
            chain.send_keys(k)
        chain.perform()

    def until_frame(self, condition, what: str) -> None:
        """Press the right arrow (Home after the last frame) until ``condition()`` holds, at most once per frame."""
        from selenium.webdriver.common.keys import Keys

        n = self.js("rt2label.state.n_frames")
        for _ in range(n + 1):
            if condition():
                return
            shown = self.js("rt2label.cur")
            self.keys(Keys.ARROW_RIGHT if shown < n - 1 else Keys.HOME)
            self.wait.until(lambda d: self.js("rt2label.cur") != shown and not self.js("rt2label.busy"))
        pytest.fail(f"no frame is {what}")

    def saved(self, frame: int) -> None:
        """Wait until the server confirmed the change of ``frame`` (the page says so only after the answer)."""
        self.wait.until(lambda d: self.text("message").startswith(f"saved frame {frame + 1}:") and not self.js("rt2label.busy"))

    def _offset(self, u, v):
        """Selenium offsets (from the canvas centre, CSS px) of image point (u, v) (COCO pixels)."""
        view = self.js("rt2label.view")
        w, h = self.js("[canvas.clientWidth, canvas.clientHeight]")
        return round(view["ox"] + u * view["scale"] - w / 2), round(view["oy"] + v * view["scale"] - h / 2)

    def click(self, u, v) -> None:
        from selenium.webdriver.common.action_chains import ActionChains

        canvas = self.d.find_element("id", "canvas")
        ActionChains(self.d).move_to_element_with_offset(canvas, *self._offset(u, v)).click().perform()

    def drag(self, u0, v0, u1, v1) -> None:
        from selenium.webdriver.common.action_chains import ActionChains

        canvas = self.d.find_element("id", "canvas")
        (x0, y0), (x1, y1) = self._offset(u0, v0), self._offset(u1, v1)
        ActionChains(self.d).move_to_element_with_offset(canvas, x0, y0).click_and_hold() \
            .move_by_offset((x1 - x0) // 2, (y1 - y0) // 2).move_by_offset(x1 - x0 - (x1 - x0) // 2, y1 - y0 - (y1 - y0) // 2) \
            .release().perform()

    @property
    def scale(self) -> float:
        return self.js("rt2label.view.scale")


def on_disk(out) -> dict:
    """file name -> (k, 4) boxes in out/annotations.json (read as rt2 train reads it)."""
    return {li.path.name: li.boxes_xywh for li in read_coco(out)}


def centre(box):
    return np.array([box[0] + box[2] / 2, box[1] + box[3] / 2])


# -- the whole story on a folder ----------------------------------------------------------------------
def test_label_by_keys_and_mouse_survive_a_kill_resume_and_train(browser, ball_folder, ball_truth, tmp_path):
    from harness.label.frames import IMAGES_DIR
    from tracker import BallSegmentationModel

    out = tmp_path / "labels"
    confirmed: dict = {}  # what the page confirmed: file name -> boxes
    server = start_label(ball_folder, out, "--min-train", 6, "--train-epochs", 1)
    try:
        page = Page(browser, server.ready["url"])
        assert "0 of 12 frames labelled" in page.text("counts")
        assert len(browser.find_elements("css selector", "#suggestions li")) == 10
        # the page opens on the first suggestion; Space walks down the list
        suggestions = page.js("rt2label.state.suggestions")
        assert page.current[0] == suggestions[0]
        page.keys(" ")
        page.wait.until(lambda d: page.js("rt2label.cur") == suggestions[1] and not page.js("rt2label.busy"))

        # Enter accepts the cyan box (the model's best proposal) as it is
        page.until_frame(lambda: page.js("rt2label.frame.proposals.length") > 0, "a frame with a proposal")
        i, key = page.current
        box = page.js("rt2label.edit.slice()")
        page.keys("\n")
        page.saved(i)
        confirmed[key] = [box]
        exact = {key}  # labels whose whole box is known; the rest are compared by their centre
        # "n": no ball
        i, key = page.current
        page.keys("n")
        page.saved(i)
        confirmed[key] = []
        # without a mouse: move the box 3 px right, 10 px down (Shift+k), grow it by 1 px a side, accept with "a"
        i, key = page.current
        x, y, w, h = page.js("rt2label.edit.slice()")
        page.keys("l", "l", "l", "K", "+", "a")
        page.saved(i)
        confirmed[key] = [[x + 3 - 1, y + 10 - 1, w + 2, h + 2]]
        exact.add(key)
        # the mouse: a click on the ball's centre, then a dragged box, each on a frame with a ball
        for how in ("click", "drag"):
            page.until_frame(lambda: len(ball_truth[page.current[1]]) > 0 and page.js("rt2label.frame.labels") is None,
                             "an unlabelled frame with a ball")
            i, key = page.current
            tx, ty, tw, th = ball_truth[key][0]
            if how == "click":
                page.click(tx + tw / 2, ty + th / 2)
            else:
                page.drag(tx, ty, tx + tw, ty + th)
            page.saved(i)
            confirmed[key] = [list(ball_truth[key][0])]
            if how == "drag":
                exact.add(key)
        # undo takes back the dragged box
        page.keys("u")
        page.wait.until(lambda d: page.text("message").startswith(f"undid the change to frame {i + 1}"))
        del confirmed[key]

        disk = on_disk(out)
        assert set(disk) == set(confirmed)
        tol = 1.0 / page.scale + 1e-6  # a click lands within half a screen pixel
        for name, boxes in confirmed.items():
            assert len(disk[name]) == len(boxes), name
            for got, want in zip(disk[name], boxes):
                assert np.abs(centre(got) - centre(want)).max() <= tol, (name, got, want)
                if name in exact:
                    np.testing.assert_allclose(got[2:], want[2:], atol=2 * tol, err_msg=name)
            assert (out / IMAGES_DIR / name).is_file()
    finally:
        server.kill()  # SIGKILL: no clean shutdown, no last write
        server.stop()
    assert set(on_disk(out)) == set(confirmed)  # every confirmed label survived the kill

    # restart on the same folder, reload the page, continue where it stopped, then train
    server = start_label(ball_folder, out, "--min-train", 6, "--train-epochs", 1)
    try:
        assert server.ready["labelled"] == len(confirmed)
        page = Page(browser, server.ready["url"])
        assert f"{len(confirmed)} of 12 frames labelled" in page.text("counts")
        for _ in range(12):
            if not page.js("rt2label.state.suggestions.length"):
                break
            i, key = page.current
            if len(ball_truth[key]):
                tx, ty, tw, th = ball_truth[key][0]
                page.click(tx + tw / 2, ty + th / 2)
            else:
                page.keys("n")
            page.saved(i)
            confirmed[key] = [list(b) for b in ball_truth[key]]
        assert "12 of 12 frames labelled" in page.text("counts")
        assert set(on_disk(out)) == set(confirmed)
        page.wait.until(lambda d: d.find_element("id", "train-btn").is_enabled())
        page.keys("t")
        from selenium.webdriver.support.ui import WebDriverWait

        WebDriverWait(browser, 600, poll_frequency=0.5).until(lambda d: page.text("train-state").startswith(("done", "failed")))
        assert page.text("train-state").startswith("done: wrote"), page.text("train-log")
        assert " at T_h=" in page.text("train-log")  # rt2 train's closing summary (thresholds, recall, outliers)
        model = BallSegmentationModel.load(out / "model.npz")
        assert "train / " in model.description
    finally:
        server.stop()


# -- a video and a session log ------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["video", "log"])
def test_video_and_session_log_load_and_label_by_keys(browser, kind, ball_video, ball_log, tmp_path):
    out = tmp_path / "labels"
    source, extra, prefix = (ball_video, (), "rally_f") if kind == "video" else (ball_log, ("--camera", "cam1"), "cam1_s")
    server = start_label(source, out, *extra)
    try:
        page = Page(browser, server.ready["url"])
        n = 12 if kind == "video" else 6
        assert f"0 of {n} frames labelled" in page.text("counts")
        assert page.current[1].startswith(prefix)
        page.until_frame(lambda: page.js("rt2label.frame.proposals.length") > 0, "a frame with a proposal")
        i, key = page.current
        page.keys("\n")
        page.saved(i)
        j, key2 = page.current  # the next suggested frame
        page.keys("n")
        page.saved(j)
        from selenium.webdriver.common.keys import Keys

        # a frame without a proposal: Enter saves nothing (no box at a made-up place) and says what to do
        page.until_frame(lambda: page.js("rt2label.frame.proposals.length") == 0 and page.js("rt2label.frame.labels") is None,
                         "an unlabelled frame without a proposal")
        page.keys("\n")
        page.wait.until(lambda d: page.text("message").startswith("no proposal in this frame: click the ball"))
        now = page.js("rt2label.cur")
        page.keys(Keys.ARROW_RIGHT if now < n - 1 else Keys.ARROW_LEFT)  # the next (previous) frame in source order
        page.wait.until(lambda d: page.js("rt2label.cur") == (now + 1 if now < n - 1 else now - 1))
        disk = on_disk(out)
        assert list(disk) == [f"{key}.png", f"{key2}.png"] and len(disk[f"{key}.png"]) == 1 and len(disk[f"{key2}.png"]) == 0
    finally:
        server.stop()
