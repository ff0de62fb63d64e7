#!/usr/bin/env python3
"""CTest view.browser: the `soma view` page of a labelled real take in a real
browser (Debian's chromium, headless; scripts/install_deps.sh installs it).

1. `soma label_eval` corrupts the real HDM05 take of ../shared/data/c3d
   (OC_05_G_03_BT_00), labels it per frame with the bundled model and scores
   it (per_frame/per_frame.csv); `soma view` writes the page of the labelled
   C3D with the corruption's ground truth (and the sidecar's confidences).
2. chromium --dump-dom loads the page (hovering an error with &hover=error): the counts the page writes into the
   data-* attributes of #status must equal the sidecar's (h5py: frames,
   points per frame, points in all), and at `#frame=N` for the first frame
   that soma eval scored below 100%, the page's accuracy must equal eval's and
   its wrong + ghost + missed count must equal eval's errors (> 0); frame 0
   (100% in eval) must show no error.
   With task.max_page_mb=2 the page (under 2 MB) shows every k-th frame,
   says so in its note, and #frame=N shows the nearest shown frame. With a
   `soma solve` of frames 0-119 (task.solve), the page shows the body mesh
   of frame 60 at #frame=60, and after a click a quarter into the timeline
   strip (#timeline=0.25) frame T/4 and no mesh.
3. chromium --screenshot of frame N and of frame 0: the 3D view of frame N
   must hold pixels of the wrong-label red or the ghost orange, frame 0's
   none. Both PNGs stay in <build>/tests/view_browser/ as artefacts.

    python3 tests/view/browser_test.py <soma binary> <source dir> <artefact dir>
"""
import html.parser
import os
import shutil
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np
from PIL import Image

TAKE = "HDM_mm_01-02_03_120"
WINDOW = (1400, 850)
PANEL_WIDTH, HEADER_HEIGHT, FOOTER_HEIGHT = 215, 75, 100  # CSS layout, px


def fail(message):
    print(f"FAIL: {message}")
    sys.exit(1)


SECONDS = {}  # wall time per program, for the summary line


def run(cmd, **kwargs):
    start = time.time()
    result = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    key = os.path.basename(cmd[0]) + ("" if "chromium" in cmd[0] else " " + cmd[1])
    SECONDS[key] = SECONDS.get(key, 0.0) + time.time() - start
    if result.returncode != 0:
        fail(f"{' '.join(cmd)} exited {result.returncode}:\n{result.stdout[-2000:]}{result.stderr[-2000:]}")
    return result.stdout


def chromium_command():
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    fail("no chromium on PATH: install it with scripts/install_deps.sh (Debian package chromium)")


def browser(chromium, profile, url, *mode):
    # Flags for a root, offline, sandbox-less headless run; WebGL through
    # SwiftShader (software), so no GPU is needed.
    return run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking", "--disable-component-update",
                "--disable-sync", f"--user-data-dir={profile}", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--hide-scrollbars", "--virtual-time-budget=2500",
                f"--window-size={WINDOW[0]},{WINDOW[1]}", *mode, url], timeout=60)


class StatusParser(html.parser.HTMLParser):
    """The attributes of <span id="status">."""

    def __init__(self):
        super().__init__()
        self.attrs = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if attrs.get("id") == "status":
            self.attrs = attrs


def page_status(chromium, profile, url):
    parser = StatusParser()
    parser.feed(browser(chromium, profile, url, "--dump-dom"))
    if parser.attrs is None:
        fail(f"{url}: no #status element in the DOM")
    if "data-error" in parser.attrs:
        fail(f"{url}: the page reports an error: {parser.attrs['data-error']}")
    if parser.attrs.get("data-ready") != "1":
        fail(f"{url}: the page did not finish loading (data-ready missing)")
    return parser.attrs


def read_png_rgb(path):
    """A PNG as an H x W x 3 uint8 array (Pillow: python3-pil, a dependency of
    python3-matplotlib in scripts/install_deps.sh)."""
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


def count_flagged(image):
    """Pixels of the 3D view (no header, panel, footer) in the hues of the
    wrong-label red (#e53935) and the ghost orange (#ff9800), lit or shaded:
    red well above green and blue. Nothing else on the page is drawn in those
    hues (correct markers green, rejected ghosts grey, sticks grey, the
    origin's axes magenta, cyan, blue)."""
    h, w, _ = image.shape
    view = image[HEADER_HEIGHT:h - FOOTER_HEIGHT, :w - PANEL_WIDTH].astype(np.int32)
    r, g, b = view[:, :, 0], view[:, :, 1], view[:, :, 2]
    return int(((r > 100) & (g < 0.75 * r) & (b < 0.5 * r)).sum())


def main():
    soma, source, artefacts = sys.argv[1:4]
    take = os.path.join(source, "..", "shared", "data", "c3d", f"{TAKE}.c3d")
    if not os.path.exists(take):
        fail(f"{take} is missing (../shared/data, see README 'Data and licences')")
    chromium = chromium_command()
    os.makedirs(artefacts, exist_ok=True)
    work = tempfile.mkdtemp(prefix="somalab_view_browser_")
    start = time.time()
    try:
        # 1. Label and score the real take; write its page.
        run([soma, "label_eval", take, "threads=1", f"hydra.run.dir={work}/label_eval"])
        labelled = f"{work}/label_eval/per_frame/{TAKE}_labeled.c3d"
        truth = f"{work}/label_eval/OC_05_G_03_BT_00/{TAKE}.h5"
        run([soma, "view", labelled, f"task.gt={truth}", "threads=1", f"hydra.run.dir={work}/view"])
        page = f"{work}/view/{TAKE}_labeled.html"
        size_mb = os.path.getsize(page) / 1e6

        # What the page must report, from files the page's code did not write.
        with h5py.File(f"{work}/label_eval/per_frame/{TAKE}_labels.h5", "r") as f:
            points_per_frame = (f["column"][:] >= 0).sum(axis=1)
        frames = len(points_per_frame)
        rows = np.genfromtxt(f"{work}/label_eval/per_frame/per_frame.csv", delimiter=",", names=True)
        bad = rows[rows["accuracy"] < 1.0]
        if len(bad) == 0:
            fail("soma eval scored every frame 100%: no labelling error to look at")
        error_frame = int(bad["frame"][0])
        error_row = bad[0]
        errors = int(round(error_row["pairs"] * (1.0 - error_row["accuracy"])))
        first = rows[rows["frame"] == 0]
        if len(first) != 1 or first["accuracy"][0] != 1.0:
            fail("soma eval did not score frame 0 at 100%; the clean-frame check needs another frame")

        # 2. Counts in the DOM.
        profile = f"{work}/profile"
        os.makedirs(profile)
        url = f"file://{os.path.abspath(page)}"
        status = page_status(chromium, profile, f"{url}#frame={error_frame}&hover=error")
        expect = {
            "data-frames": str(frames),
            "data-shown-frames": str(frames),
            "data-points": str(int(points_per_frame.sum())),
            "data-frame": str(error_frame),
            "data-frame-points": str(int(points_per_frame[error_frame])),
            "data-webgl": "ok",
        }
        for key, value in expect.items():
            if status.get(key) != value:
                fail(f"#frame={error_frame}: {key} = {status.get(key)}, expected {value}")
        shown_errors = sum(int(status[k]) for k in ("data-frame-wrong", "data-frame-ghost", "data-frame-missed"))
        if shown_errors != errors or shown_errors == 0:
            fail(f"#frame={error_frame}: the page shows {shown_errors} errors, soma eval counts {errors}")
        if abs(float(status["data-frame-accuracy"]) - error_row["accuracy"]) > 1e-6:
            fail(f"#frame={error_frame}: accuracy {status['data-frame-accuracy']}, soma eval {error_row['accuracy']}")
        # Hovering (a real mousemove at the marker's projection) a point that
        # is labelled wrong shows its label, its true label, the error, its
        # confidence and trajectory.
        tip = dict(line.split(None, 1) if " " in line else (line, "")
                   for line in status.get("data-hover", "").replace("true label", "true_label").splitlines())
        if tip.get("status", "").strip() not in ("WRONG", "ghost labelled as marker", "missed (labelled null)") or \
                tip.get("label") == tip.get("true_label") or "confidence" not in tip or \
                not tip.get("trajectory", "").strip().lstrip("-").isdigit():
            fail(f"#frame={error_frame}&hover=error: tooltip {status.get('data-hover')!r}")
        clean = page_status(chromium, profile, f"{url}#frame=0")
        clean_errors = sum(int(clean[k]) for k in ("data-frame-wrong", "data-frame-ghost", "data-frame-missed"))
        if clean.get("data-frame") != "0" or clean_errors != 0:
            fail(f"#frame=0: frame {clean.get('data-frame')} with {clean_errors} errors, expected frame 0 with none")

        # A page over its size limit shows every k-th frame and says so.
        run([soma, "view", labelled, f"task.gt={truth}", "task.max_page_mb=2", "threads=1",
             f"hydra.run.dir={work}/view_small"])
        small_page = f"{work}/view_small/{TAKE}_labeled.html"
        if os.path.getsize(small_page) > 2e6:
            fail(f"{small_page}: {os.path.getsize(small_page)} bytes, above task.max_page_mb=2")
        parser = StatusParser()
        dom = browser(chromium, profile, f"file://{os.path.abspath(small_page)}#frame={error_frame}", "--dump-dom")
        parser.feed(dom)
        small = parser.attrs or {}
        step = int(small.get("data-frame-step", "0"))
        if step < 2 or small.get("data-frames") != str(frames) or \
                small.get("data-shown-frames") != str((frames + step - 1) // step):
            fail(f"task.max_page_mb=2: step {step}, frames {small.get('data-frames')}, "
                 f"shown {small.get('data-shown-frames')}; expected a step > 1 over {frames} frames")
        lower = error_frame // step * step  # the nearest shown frame, ties to the lower
        upper = lower + step
        nearest = upper if upper < frames and upper - error_frame < error_frame - lower else lower
        if small.get("data-frame") != str(nearest):
            fail(f"task.max_page_mb=2, #frame={error_frame}: shows frame {small.get('data-frame')}, "
                 f"expected the nearest shown frame {nearest}")
        if f"1 frame in {step} is shown" not in dom or '<div id="note" hidden' in dom:
            fail("task.max_page_mb=2: the page does not show its subsampling note")

        # A body fit of the first 120 frames: meshes near those frames only.
        run([soma, "solve", labelled, "solver.end=120", "threads=1", f"hydra.run.dir={work}/solve"])
        run([soma, "view", labelled, f"task.solve={work}/solve/{TAKE}_labeled_stageii.h5", "threads=1",
             f"hydra.run.dir={work}/view_body"])
        body_url = f"file://{os.path.abspath(work)}/view_body/{TAKE}_labeled.html"
        # (#timeline=0.25: a click a quarter into the timeline strip jumps to
        # frame floor(0.25 F), far from the fitted frames.)
        quarter = frames // 4
        for query, frame, mesh in (("frame=60", 60, "60"), ("frame=60&timeline=0.25", quarter, "")):
            body = page_status(chromium, profile, f"{body_url}#{query}")
            if body.get("data-frame") != str(frame) or body.get("data-mesh-frame") != mesh or \
                    body.get("data-webgl") != "ok":
                fail(f"body page #{query}: frame {body.get('data-frame')}, mesh frame "
                     f"{body.get('data-mesh-frame')!r} (webgl {body.get('data-webgl')}), "
                     f"expected frame {frame}, mesh {mesh!r}")

        # 3. What the 3D view shows.
        shot = os.path.join(artefacts, f"{TAKE}_frame{error_frame}.png")
        shot_clean = os.path.join(artefacts, f"{TAKE}_frame0.png")
        browser(chromium, profile, f"{url}#frame={error_frame}", f"--screenshot={shot}")
        browser(chromium, profile, f"{url}#frame=0", f"--screenshot={shot_clean}")
        image, image_clean = read_png_rgb(shot), read_png_rgb(shot_clean)
        if image.shape[:2] != (WINDOW[1], WINDOW[0]):
            fail(f"{shot}: {image.shape[1]} x {image.shape[0]} px, expected {WINDOW[0]} x {WINDOW[1]}")
        flagged, flagged_clean = count_flagged(image), count_flagged(image_clean)
        if flagged == 0:
            fail(f"{shot}: no red or orange marker in the 3D view of frame {error_frame}")
        if flagged_clean != 0:
            fail(f"{shot_clean}: {flagged_clean} red/orange pixels in the 3D view of the error-free frame 0")
        print(f"ok (subsampled page: 1 frame in {step}): {frames} frames, {int(points_per_frame.sum())} points; frame {error_frame}: "
              f"{status['data-frame-points']} points, {shown_errors} errors "
              f"({status['data-frame-wrong']} wrong, {status['data-frame-ghost']} ghosts, "
              f"{status['data-frame-missed']} missed) = soma eval's; hover: {tip['label'].strip()} (true "
              f"{tip['true_label'].strip()}, {tip['status'].strip()}); {flagged} red/orange px "
              f"(frame 0: {flagged_clean}); page {size_mb:.1f} MB; {time.time() - start:.1f} s (" +
              ", ".join(f"{k} {v:.1f} s" for k, v in SECONDS.items()) + "); "
              f"screenshots in {artefacts}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
