"""The HTML report: its content, and that it works in a real browser (headless Chromium).

The browser test drives Debian's ``chromium`` through the Chrome DevTools protocol: it opens the
report from disk with no network, collects console errors, uncaught exceptions and failed loads,
checks that every image decoded and that the 3D view rendered a non-blank picture.
"""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from freqbrdf import pipeline
from freqbrdf.capture.layouts import load
from freqbrdf.cli import main
from freqbrdf.config import Config, TexelConfig
from freqbrdf.outputs.evaluate import evaluate_fit
from freqbrdf.outputs.fit_folder import load_fit
from freqbrdf.outputs.relight import RelightSettings
from freqbrdf.outputs.report import REPORT_FILE, _std_calibration_sentence, _timing_rows, write_report
from freqbrdf.synthetic import demo
from freqbrdf.synthetic.synth import SynthSettings, synthesize

TINY = SynthSettings(mesh="bunny", views=6, resolution=40, spp=4, texture_res=32, test_views=1, test_envmaps=1)
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.fixture(scope="module")
def fit_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    capture_dir = synthesize(root / "capture", TINY, progress=False)
    capture = load(capture_dir)
    config = Config(texels=TexelConfig(texture_res=32))
    folder = pipeline.write_fit(root / "fit", pipeline.fit(capture, config), config)
    evaluate_fit(load_fit(folder), capture, settings=RelightSettings(spp=2))
    return folder


@pytest.mark.slow
def test_report_has_every_section_and_its_files(fit_folder):
    page = write_report(fit_folder)
    text = page.read_text(encoding="utf-8")
    for section in ("viewer", "maps", "uncertainty", "spectra", "evaluation", "timings"):
        assert f'id="{section}"' in text, section
    assert "Not shown" not in text  # every input was there
    for source in re.findall(r'src="([^"]+)"', text):
        assert (page.parent / source).is_file(), source
    assert "http://" not in text and "https://" not in text  # nothing from the network
    # The roughness std map beside the entropy, what it means, and its Spearman from the evaluation.
    assert 'src="roughness_std.png"' in text and "how far the estimated roughness itself may be off" in text
    metrics = json.loads((fit_folder / "evaluation" / "metrics.json").read_text())
    assert f"Spearman &rho; {metrics['uncertainty']['roughness_std']['roughness']['spearman']:.2f}" in text
    models = (page.parent / "models.js").read_text()
    assert models.count("data:model/gltf-binary;base64,") == 3  # material, entropy overlay and trust mask
    assert 'data-model="trust"' in text and 'src="trust.png"' in text
    assert "(calibrated mode, 8 x 8 hypotheses)" in text  # what the entropy scored
    assert "It says how ambiguous the light makes the material" in text  # and what that means
    # The capture named relative to the fit folder, never by its absolute path.
    assert "<code>../capture</code>" in text and str(fit_folder.parent.resolve()) not in text
    # The buttons say which is shown; the overlay, the maps and the error images have colour bars.
    assert 'data-model="material" aria-pressed="true"' in text and 'data-model="entropy" aria-pressed="false"' in text
    assert 'id="overlay-colourbar"' in text
    assert {"viridis", "magma"} <= set(re.findall(r'class="colourbar" data-colormap="(\w+)"', text))
    assert "<th>reference | estimate, relit | error</th>" in text
    # Every image sits in a figure with a caption.
    figures = re.findall(r"<figure>(.*?)</figure>", text, flags=re.S)
    assert len(re.findall(r"<img ", text)) == sum(figure.count("<img ") for figure in figures)
    assert all(re.search(r"<figcaption>[^<]+", figure) for figure in figures)
    # The held-out std calibration, as summary.json records it.
    assert "Std calibration: 4 folds of held-out views" in text
    # Timings: "write" before "total", the total last.
    stages = re.findall(r"<tr class=\"(?:stage|sub)\"><td>([^<]+)</td>", text)
    assert stages[-2:] == ["write", "total"]


def test_std_calibration_sentence_names_the_factors_and_the_held_out_coverage():
    found = {"folds": 4, "texels": 120, "factors": {"roughness": 1.0, "base_color": 2.5},
             "coverage_before": {"roughness": 0.8, "base_color": 0.4},
             "coverage_after": {"roughness": 0.8, "base_color": 0.7}}
    assert _std_calibration_sentence(found) == (
        "Std calibration: 4 folds of held-out views on 120 texels scaled the std maps by roughness × 1.00, "
        "base colour × 2.50 (held-out deviations within one std: 80% → 80%, 40% → 70%).")
    assert _std_calibration_sentence(None) == "" and _std_calibration_sentence({"factors": {}}) == ""


def test_timing_rows_leave_out_zero_sub_stages_and_end_with_write_and_total():
    timings = {"observe": 2.0, "observe.raster": 1e-7, "observe.fits": 0.5, "estimate": 3.0, "textures": 0.001,
               "total": 5.0, "write": 0.25, "note": "not a number"}
    assert _timing_rows(timings) == [("observe", 2.0), ("observe.fits", 0.5), ("estimate", 3.0), ("textures", 0.001),
                                     ("write", 0.25), ("total", 5.25)]
    assert _timing_rows({"estimate": 1.0}) == [("estimate", 1.0)]


@pytest.mark.slow
def test_report_without_evaluation_says_what_is_missing(fit_folder, tmp_path, monkeypatch):
    bare = tmp_path / "fit"
    shutil.copytree(fit_folder, bare, ignore=shutil.ignore_patterns("evaluation", "report"))
    monkeypatch.setattr(sys, "argv", ["freqbrdf", "report", str(bare), "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert (exit_info.value.code or 0) == 0
    assert "run `freqbrdf evaluate FIT` first" in (bare / "report" / REPORT_FILE).read_text()


def test_report_of_a_folder_that_is_not_a_fit_fails_cleanly(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["freqbrdf", "report", str(tmp_path)])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2 and "summary.json" in capsys.readouterr().err
    assert not (tmp_path / "report").exists()


@pytest.mark.slow
def test_demo_writes_a_report_and_reuses_its_cached_capture(tmp_path, monkeypatch):
    config = Config(texels=TexelConfig(texture_res=32))
    first = demo.run_demo(tmp_path, TINY, config, relight=RelightSettings(spp=2))
    assert not first["capture_cached"] and Path(first["report"]).is_file()
    assert first["texture"]["texels"] > 0 and first["relighting"]["psnr_hdr"] > 0

    def must_not_render(*args, **kwargs):
        raise AssertionError("the cached capture was rendered again")

    monkeypatch.setattr(demo, "synthesize", must_not_render)
    second = demo.run_demo(tmp_path, TINY, config, relight=RelightSettings(spp=2))
    assert second["capture_cached"] and second["capture"] == first["capture"]
    # Other settings are another capture: the cache key is the settings.
    assert demo.capture_folder(tmp_path, TINY) != demo.capture_folder(tmp_path, dataclasses.replace(TINY, spp=8))


# --- in a browser -----------------------------------------------------------------------------


class DevTools:
    """A minimal Chrome DevTools protocol client over one page's websocket."""

    def __init__(self, url: str):
        import websocket  # test extra (websocket-client)

        self.socket = websocket.create_connection(url, timeout=60)
        self.next_id = 0
        self.events: list[dict] = []

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.recv())
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})
            self.events.append(message)

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")


def start_chromium(profile: Path) -> tuple[subprocess.Popen, str]:
    process = subprocess.Popen(
        [CHROMIUM, "--headless", "--no-sandbox", "--no-first-run", "--disable-gpu",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--remote-debugging-port=0",
         f"--user-data-dir={profile}", "--window-size=1100,1400", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        start_new_session=True,  # its own process group: `stop_chromium` ends its helpers too
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = process.stderr.readline()
        match = re.search(r"DevTools listening on (ws://\S+)", line)
        if match:
            return process, match.group(1)
        if not line and process.poll() is not None:
            break
    stop_chromium(process)
    raise RuntimeError("chromium did not start its DevTools endpoint")


def stop_chromium(process: subprocess.Popen) -> None:
    """Kill chromium and its helper processes (renderer, GPU, crash handler): killing the main one
    alone let a helper write into the profile while its temporary folder was being removed."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait()


def page_websocket(browser_url: str) -> str:
    import websocket

    browser = websocket.create_connection(browser_url, timeout=60)
    browser.send(json.dumps({"id": 1, "method": "Target.createTarget", "params": {"url": "about:blank"}}))
    target = json.loads(browser.recv())["result"]["targetId"]
    browser.close()
    port = re.search(r":(\d+)/", browser_url).group(1)
    return f"ws://127.0.0.1:{port}/devtools/page/{target}"


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's `chromium` (make test installs it when run as root)")
def test_report_works_in_headless_chromium(fit_folder):
    pytest.importorskip("websocket", reason="needs the test extra websocket-client (pip install -e '.[test]')")
    page = write_report(fit_folder)
    with tempfile.TemporaryDirectory() as profile:
        process, browser_url = start_chromium(Path(profile))
        try:
            tools = DevTools(page_websocket(browser_url))
            for domain in ("Runtime", "Log", "Page"):
                tools.call(f"{domain}.enable")
            tools.call("Page.navigate", url=page.as_uri())
            # Wait for the page and the glTF: model-viewer's `loaded` turns true once the model is in.
            state = tools.evaluate("""new Promise(resolve => {
                const started = Date.now();
                const poll = () => {
                  const viewer = document.getElementById('model');
                  const images = [...document.images];
                  const done = document.readyState === 'complete' && viewer && viewer.loaded
                               && images.every(i => i.complete);
                  if (done || Date.now() - started > 45000) {
                    resolve({ready: !!done, images: images.length,
                             broken: images.filter(i => i.naturalWidth === 0).map(i => i.src)});
                  } else { setTimeout(poll, 200); }
                };
                poll();
            })""")
            assert state["ready"], state
            assert state["images"] >= 10 and state["broken"] == []
            # Take model-viewer's own picture of its canvas once it has rendered: software GL on a
            # loaded machine can take seconds for the first frames, so poll (1 s apart, up to 30 s).
            for _ in range(30):
                picture_url = tools.evaluate(
                    "new Promise(r => setTimeout(() => r(document.getElementById('model').toDataURL('image/png')), 1000))"
                )
                picture = np.asarray(Image.open(io.BytesIO(base64.b64decode(picture_url.split(",", 1)[1]))).convert("RGB"))
                # Non-blank: a good share of pixels differ from the corner (background) colour.
                background = picture[2, 2].astype(int)
                differs = np.abs(picture.astype(int) - background).sum(axis=-1) > 30
                if differs.mean() > 0.03:
                    break
            assert picture.shape[0] > 100 and picture.shape[1] > 100
            assert differs.mean() > 0.03, f"3D view looks blank ({differs.mean():.3%} non-background pixels)"
            # Every image has a caption; the shown model's button is pressed and looks it.
            assert tools.evaluate("""[...document.images].every(image => {
                const caption = image.closest('figure')?.querySelector('figcaption');
                return caption && caption.textContent.trim().length > 10; })""")
            buttons_state = """(() => {
                const state = {};
                for (const button of document.querySelectorAll('button[data-model]')) {
                  state[button.dataset.model] = {pressed: button.getAttribute('aria-pressed'),
                                                 background: getComputedStyle(button).backgroundColor};
                }
                const bar = document.getElementById('overlay-colourbar');
                state.bar = {visible: !!bar && !bar.hidden && bar.offsetWidth > 0,
                             gradient: !!bar && getComputedStyle(bar.querySelector('.bar')).backgroundImage};
                return state; })()"""
            before = tools.evaluate(buttons_state)
            assert before["material"]["pressed"] == "true" and before["entropy"]["pressed"] == "false"
            assert before["material"]["background"] != before["entropy"]["background"]
            assert not before["bar"]["visible"]
            # The overlay switch loads the entropy model without errors.
            switched = tools.evaluate("""new Promise(resolve => {
                const viewer = document.getElementById('model');
                viewer.addEventListener('load', () => resolve(viewer.src.startsWith('data:')), {once: true});
                document.querySelector('button[data-model=entropy]').click();
                setTimeout(() => resolve(false), 30000);
            })""")
            assert switched
            after = tools.evaluate(buttons_state)
            assert after["entropy"]["pressed"] == "true" and after["material"]["pressed"] == "false"
            assert after["entropy"]["background"] == before["material"]["background"]
            assert after["bar"]["visible"] and "linear-gradient" in after["bar"]["gradient"]
            # At 600 px wide the page does not scroll sideways (wide tables scroll inside their box).
            tools.call("Emulation.setDeviceMetricsOverride", width=600, height=900, deviceScaleFactor=1, mobile=False)
            widths = tools.evaluate("""new Promise(resolve => requestAnimationFrame(() => requestAnimationFrame(() =>
                resolve({scroll: document.scrollingElement.scrollWidth, client: document.scrollingElement.clientWidth,
                         inner: window.innerWidth}))))""")
            assert widths["inner"] == 600 and widths["scroll"] <= widths["client"], widths
            # From 1000 to 1920 px every row fits: it wraps or its pictures scale, so neither the page
            # nor any box inside it (the map tables' scroll boxes) scrolls sideways.
            for width in (1000, 1280, 1400, 1920):
                tools.call("Emulation.setDeviceMetricsOverride", width=width, height=1000, deviceScaleFactor=1,
                           mobile=False)
                fits = tools.evaluate("""new Promise(resolve => requestAnimationFrame(() => requestAnimationFrame(() => {
                    const page = document.scrollingElement;
                    const boxes = [...document.querySelectorAll('.scroll')].map(box => ({
                        section: box.closest('section')?.id, scroll: box.scrollWidth, client: box.clientWidth}));
                    resolve({inner: window.innerWidth, scroll: page.scrollWidth, client: page.clientWidth,
                             wide_boxes: boxes.filter(box => box.scroll > box.client)});
                })))""")
                assert fits["inner"] == width and fits["scroll"] <= fits["client"], fits
                assert fits["wide_boxes"] == [], fits
            tools.call("Runtime.evaluate", expression="0")  # flush pending events into tools.events
            problems = [
                event["params"] for event in tools.events
                if event.get("method") == "Runtime.exceptionThrown"
                or (event.get("method") == "Runtime.consoleAPICalled" and event["params"]["type"] == "error")
                or (event.get("method") == "Log.entryAdded" and event["params"]["entry"]["level"] == "error"
                    and "GL Driver" not in event["params"]["entry"].get("text", ""))
            ]
            assert problems == []
        finally:
            stop_chromium(process)
