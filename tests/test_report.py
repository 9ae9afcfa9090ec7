"""The HTML report of a finished study (`snakemake --report results/<study>/report.html`).

Snakemake (>= 8) writes the report after the run, as one self-contained HTML
file: a JavaScript app in which every result is embedded as a base64 data URI.
The tests generate it for the finished analytic study (fixture ``done_run``,
tests/conftest.py) and check that it holds every figure of summary.json, the
summary itself and the captions (workflow/report/*.rst); one opens it in
headless Chromium (driven over the DevTools protocol), navigates the app as a
user would (category, result, eye button, info button) and checks that each
figure renders: the displayed image is the figure's PNG, decoded at its pixel
size and not blank, and its caption is shown. Without a chromium binary that
test is skipped (Debian: apt-get install -y chromium).
"""

from __future__ import annotations

import base64
import fcntl
import html
import json
import os
import re
import select
import shutil
import struct
import subprocess
import time
from pathlib import Path

import pytest
from _workflow_helpers import REPO, smk

pytestmark = pytest.mark.workflow

CAPTIONS = REPO / "workflow" / "report"

# Report category of each figure family (workflow/rules/figures.smk); the
# subcategory is the measure for per-measure figures. The caption of family
# ``f`` is workflow/report/<f>.rst.
CATEGORY = {
    "response": "Likelihood response surfaces",
    "convergence": "GP convergence",
    "joint": "Posterior",
    "particles": "Posterior",
    "marginals": "Posterior",
    "pairs": "Posterior",
    "parallel": "Posterior",
    "interfaces": "Interfaces",
    "fields": "Ground truth fields",
    "rounds": "Active design",
    "segmentation": "Observations",
}


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _caption_start(family: str, measure: str | None) -> str:
    """The first words of a caption as the report shows them (whitespace collapsed)."""
    text = (CAPTIONS / f"{family}.rst").read_text()
    text = re.sub(r"\{\{\s*snakemake\.wildcards\.measure\s*\}\}", measure or "", text)
    return " ".join(text.split())[:80]


def _png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    return struct.unpack(">II", data[16:24])


def _decode_data_uri(uri: str) -> bytes:
    head, _, payload = uri.partition(",")
    assert head.startswith("data:") and head.endswith(";base64"), head[:80]
    return base64.b64decode(payload)


@pytest.fixture(scope="module")
def report(done_run, tmp_path_factory):
    """(report path, expected entries) for the finished analytic study."""
    path = tmp_path_factory.mktemp("report") / "report.html"
    made = smk(done_run, "--report", str(path))  # not in done_run: shared, left unmodified
    # a report outside the study's folder is made, with a note saying where one per study goes
    assert (f"bayescalib: note: the report goes to {path}, outside results/analytic/"
            in made.stderr), made.stderr[-2000:]
    summary = json.loads((done_run / "results" / "analytic" / "summary.json").read_text())
    expected = [{
        "path": "results/analytic/summary.json", "category": "Summary", "subcategory": "Other",
        "kind": "data", "caption": _caption_start("summary", None),
    }]
    for key, files in summary["figures"].items():
        measure, _, family = key.rpartition("/")
        for f in files:
            if f.endswith(".png"):
                expected.append({
                    "path": f, "category": CATEGORY[family], "subcategory": measure or "Other",
                    "kind": "image", "caption": _caption_start(family, measure or None),
                })
    # summary, response, 3 posterior (joint, particles, marginals: no pairs or parallel
    # axes for two parameters, the joint shows all they would), interfaces
    assert len(expected) == 1 + 5, expected
    assert not any(e["path"].endswith(("pairs.png", "parallel.png")) for e in expected)
    return path, expected


def test_the_front_page_renders_as_snakemakes_report_renders_it(tmp_path, monkeypatch):
    """workflow.rst through Jinja with Snakemake's settings (trim_blocks, lstrip_blocks:
    a newline after a block tag is dropped) and docutils: the verdict, the joint
    posterior embedded as a data URI, the table with its header row."""
    import jinja2
    from docutils.core import publish_parts
    from PIL import Image

    from bayescalib.stages.summary import front_page

    monkeypatch.chdir(tmp_path)
    Path("fig").mkdir()
    Image.new("RGB", (300, 200), (30, 90, 200)).save("fig/joint.png")
    summary = {
        "study": "analytic", "measure": "rkhs", "parameters": [{"name": "E", "unit": "Pa"}],
        "map": {"E": 401.0}, "posterior_mean": {"E": 402.0}, "posterior_sd": {"E": 12.0},
        "posterior_cov": [[144.0]], "credible_intervals": {"E": {"0.9": [380.0, 420.0]}},
        "ground_truth": {"E": 400.0}, "n_train": 20, "n_failed": 0,
        "fit": {"misfit_nats": 600.0, "expected_nats": 0.5, "expected_sd_nats": 0.71,
                "consistent": False, "words": "the best solve misfits the data"},
        "design": {"strategy": "active", "n_solves": 20, "n_failed": 0, "converged": True,
                   "max_solves": 40, "reason": "converged after round 2 with 20 solves",
                   "rounds": []},
        "figures": {"rkhs/joint": ["fig/joint.png"]}}
    Path("summary.json").write_text(json.dumps(summary))
    fp = front_page("summary.json", embed_figure=True)
    assert front_page("summary.json")["figure_uri"] is None  # outside a report: no copy
    env = jinja2.Environment(trim_blocks=True, lstrip_blocks=True)
    snakemake = type("S", (), {"config": {"study": "analytic", "front_page": fp,
                                          "report_flags": {"ground_truth": True}}})
    rst = env.from_string((CAPTIONS / "workflow.rst").read_text()).render(snakemake=snakemake)
    page = publish_parts(rst, writer="html")["html_body"]
    assert "System Message" not in page, page[:2000]
    assert "<strong>Verdict.</strong> The best fit is 1200 times worse than the noise" in page
    data = base64.b64encode(Path("fig/joint.png").read_bytes()).decode()
    assert f'src="data:image/png;base64,{data}"' in page
    assert "<thead" in page and "header-rows" not in page  # the option was read as one
    assert "<caption>Posterior (rkhs measure): MAP, mean, standard deviation, 90 % " \
           "equal-tailed interval, ground truth</caption>" in page


def test_every_figure_family_has_a_caption():
    for family in CATEGORY:
        assert (CAPTIONS / f"{family}.rst").read_text().strip(), family
    assert (CAPTIONS / "summary.rst").read_text().strip()
    assert (CAPTIONS / "workflow.rst").read_text().strip()


def test_report_is_one_html_file_embedding_every_figure_and_the_summary(report, done_run):
    path, expected = report
    text = path.read_text()
    assert text.lstrip().lower().startswith("<!doctype html"), "the report is not an HTML file"
    # Snakemake's report app shows the workflow description and the captions
    assert "Bayesian calibration of the study <strong>analytic</strong>" in text
    # its front page: the verdict, and the joint posterior embedded in it (an <img> of
    # the figure's own PNG, beside its entry among the results)
    summary = json.loads((done_run / "results/analytic/summary.json").read_text())
    assert "<strong>Verdict.</strong>" in text
    joint = base64.b64encode((done_run / summary["figures"]["rkhs/joint"][0]).read_bytes())
    assert text.count(joint.decode()) == 2, "the joint posterior is not on the front page"
    for entry in expected:
        data = (done_run / entry["path"]).read_bytes()
        assert base64.b64encode(data).decode() in text, f"{entry['path']} not embedded"
    # captions are HTML in JSON strings: compare their first words, whitespace collapsed
    flat = re.sub(r"(?:\\n|\s)+", " ", text)
    for entry in expected:
        words = json.dumps(html.escape(entry["caption"][:60], quote=False))[1:-1]
        assert words in flat, f"caption of {entry['path']} missing: {entry['caption'][:60]!r}"
    for category in {e["category"] for e in expected}:
        assert json.dumps(category) in text, category


# Evaluated in the loaded report page: navigates to each expected result as a
# user would (category, subcategory if listed, the result's eye and info
# buttons) and returns what it saw. Snakemake 9's report app: menu items are
# links in <ul>, breadcrumbs in <ol>, results in a table with buttons marked by
# their icon name.
PROBE = r"""
async function (expected) {
  const out = {entries: {}};
  const wait = ms => new Promise(r => setTimeout(r, ms));
  async function until(fn, what) {
    for (const t0 = Date.now(); Date.now() - t0 < 20000; await wait(20)) {
      const v = fn();
      if (v) return v;
    }
    throw new Error("not shown in the report: " + what);
  }
  const norm = s => s.replace(/\s+/g, " ").trim();
  const link = text => Array.from(document.querySelectorAll("nav ul a")).find(
    a => a.textContent.trim() === text);
  const row = path => Array.from(document.querySelectorAll("nav tr")).find(
    tr => tr.querySelector("td") && tr.querySelector("td").textContent.trim() === path);
  const button = (tr, icon) => Array.from(tr.querySelectorAll("a")).find(
    a => a.getAttribute("iconname") === icon);
  const shown = () => Array.from(document.querySelectorAll("img")).find(im => !im.closest("nav"));
  await until(() => link(expected[0].category), "the results menu");
  for (const exp of expected) {
    const entry = out.entries[exp.path] = {};
    try {
      document.querySelector("nav nav ol a").click();  // first breadcrumb: the main menu
      (await until(() => link(exp.category), "category " + exp.category)).click();
      await until(() => row(exp.path) || link(exp.subcategory), exp.path);
      if (!row(exp.path)) { link(exp.subcategory).click(); entry.subcategoryMenu = true; }
      const tr = await until(() => row(exp.path), exp.path + " in " + exp.category);
      entry.listed = true;
      const eye = button(tr, "eye");
      if (exp.kind === "image") {
        const before = shown() ? shown().getAttribute("src") : null;
        eye.click();
        const img = await until(() => {
          const im = shown();
          return im && im.getAttribute("src") !== before && im;
        }, "image " + exp.path);
        await img.decode();
        const box = img.getBoundingClientRect();
        entry.src = img.getAttribute("src");
        entry.natural = [img.naturalWidth, img.naturalHeight];
        entry.displayed = [box.width, box.height];
        const canvas = document.createElement("canvas");
        canvas.width = img.naturalWidth;
        canvas.height = img.naturalHeight;
        const ctx = canvas.getContext("2d");
        ctx.drawImage(img, 0, 0);
        const px = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
        const colours = new Set();
        let ink = 0;
        for (let i = 0; i < px.length; i += 4) {
          if (px[i + 3] > 0 && (px[i] < 230 || px[i + 1] < 230 || px[i + 2] < 230)) ink++;
          if (colours.size < 64) colours.add(px[i] + "," + px[i + 1] + "," + px[i + 2]);
        }
        entry.colours = colours.size;
        entry.ink = ink / (px.length / 4);
      } else {
        entry.href = eye.getAttribute("href");
      }
      button(row(exp.path), "information-circle").click();
      await until(() => norm(document.querySelector("nav").textContent).includes(exp.caption),
                  "caption of " + exp.path);
      entry.caption = true;
    } catch (err) {
      entry.error = String(err);
      entry.nav = norm(document.querySelector("nav").textContent).slice(0, 500);
    }
  }
  return out;
}
"""


class DevTools:
    """Headless Chromium driven over the DevTools protocol on a pipe
    (--remote-debugging-pipe: commands on fd 3, replies on fd 4, NUL-separated
    JSON); standard library only, real-time waits."""

    def __init__(self, chromium: str, tmp: Path):
        # pipe ends above fd 4 (and close-on-exec), so that the child can dup2 them to 3 and 4
        to_r, self._to_w, self._from_r, from_w = (
            self._high(fd) for fd in (*os.pipe(), *os.pipe()))

        def child_fds():
            os.dup2(to_r, 3)
            os.dup2(from_w, 4)

        args = ["--headless", "--disable-gpu", "--no-sandbox", "--disable-dev-shm-usage",
                "--no-first-run", "--remote-debugging-pipe", f"--user-data-dir={tmp / 'profile'}",
                "--window-size=1600,1000", "about:blank"]
        self.log = tmp / "chromium.log"
        with self.log.open("wb") as log:
            self.proc = subprocess.Popen(
                [chromium, *args], stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                close_fds=False, preexec_fn=child_fds)  # noqa: PLW1509 - only dup2 in the child, before exec
        os.close(to_r)
        os.close(from_w)
        self._buf = b""
        self._id = 0
        self.events: list[dict] = []

    @staticmethod
    def _high(fd: int) -> int:
        new = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
        os.close(fd)
        return new

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._from_r], [], [], left)[0]:
                raise TimeoutError(f"chromium did not answer; log:\n{self.log_tail()}")
            chunk = os.read(self._from_r, 1 << 20)
            if not chunk:
                raise RuntimeError(f"chromium exited; log:\n{self.log_tail()}")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = 60) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]
            self.events.append(reply)

    def wait_event(self, method: str, timeout: float = 60) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            for i, ev in enumerate(self.events):
                if ev.get("method") == method:
                    return self.events.pop(i)
            self.events.append(self._read(deadline))

    def log_tail(self) -> str:
        return self.log.read_text(errors="replace")[-3000:]

    def close(self):
        try:
            self.send("Browser.close", timeout=10)
        except (OSError, RuntimeError, TimeoutError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._to_w)
        os.close(self._from_r)


def _render(chromium: str, report_path: Path, expected: list[dict], tmp: Path) -> dict:
    """Open the report in headless Chromium and run PROBE in it."""
    browser = DevTools(chromium, tmp)
    try:
        target = browser.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = browser.send("Target.attachToTarget",
                               {"targetId": target, "flatten": True})["sessionId"]
        browser.send("Page.enable", session=session)
        browser.send("Runtime.enable", session=session)
        browser.send("Page.navigate", {"url": report_path.as_uri()}, session=session)
        browser.wait_event("Page.loadEventFired", timeout=120)
        reply = browser.send("Runtime.evaluate", {
            "expression": f"({PROBE})({json.dumps(expected)})",
            "awaitPromise": True, "returnByValue": True,
        }, session=session, timeout=300)
        assert "exceptionDetails" not in reply, reply["exceptionDetails"]
        seen = reply["result"]["value"]
        seen["exceptions"] = [ev["params"]["exceptionDetails"] for ev in browser.events
                              if ev.get("method") == "Runtime.exceptionThrown"]
        return seen
    finally:
        browser.close()


@pytest.mark.skipif(_chromium() is None,
                    reason="no chromium binary (Debian: apt-get install -y chromium)")
def test_report_renders_every_figure_in_headless_chromium(report, done_run, tmp_path):
    path, expected = report
    seen = _render(_chromium(), path, expected, tmp_path)
    assert not seen["exceptions"], f"the report app threw: {seen['exceptions']}"
    for exp in expected:
        entry = seen["entries"][exp["path"]]
        where = f"{exp['path']} ({exp['category']})"
        assert "error" not in entry, f"{where}: {entry['error']}\nnavbar: {entry.get('nav')}"
        assert entry["listed"] and entry["caption"], where
        data = (done_run / exp["path"]).read_bytes()
        if exp["kind"] == "data":
            assert _decode_data_uri(entry["href"]) == data, where
            continue
        assert _decode_data_uri(entry["src"]) == data, f"{where}: another image is shown"
        assert tuple(entry["natural"]) == _png_size(data), f"{where}: not decoded: {entry}"
        assert min(entry["displayed"]) > 0, f"{where}: not displayed: {entry['displayed']}"
        assert entry["colours"] >= 8 and entry["ink"] > 0.02, f"{where}: blank image: {entry}"


# extended suite (pytest -m extended, run by .ci/run): a longer variant of a check the
# default suite makes; kept out of the default suite for its time
@pytest.mark.extended
def test_each_figure_is_in_the_report_once_png_and_the_pdf_on_disk(tmp_path, base_study):
    """With formats [png, pdf] the report embeds the PNG of each figure and not the PDF
    (each figure once); the PDF is written next to it for print."""
    import yaml

    study = json.loads(json.dumps(base_study))
    study["plots"]["formats"] = ["png", "pdf"]
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "config.yaml").write_text(yaml.safe_dump(study))
    smk(tmp_path)
    made = smk(tmp_path, "--report", "results/analytic/report.html")
    assert "bayescalib: note: the report goes to" not in made.stderr  # the study's own path
    text = (tmp_path / "results" / "analytic" / "report.html").read_text()
    # captions carry the study's own numbers
    assert "Shown in numbers: E = " in text and "This study: bayescalib analytic: E = " in text
    figs = tmp_path / "results" / "analytic" / "figures" / "rkhs"
    for fam in ("joint", "marginals"):
        assert (figs / f"{fam}.pdf").stat().st_size > 1000
        assert base64.b64encode((figs / f"{fam}.png").read_bytes()).decode() in text
        assert base64.b64encode((figs / f"{fam}.pdf").read_bytes()).decode()[:4000] not in text


def test_a_report_of_an_unfinished_or_live_study_says_so(tmp_path, base_study):
    """Not Snakemake's "summary.json marked for report but does not exist": the study
    has not been run, its run has not finished, or it is being run right now, and what
    to do (no workflow run needed: the refusal comes when the Snakefile is read)."""
    import subprocess
    import sys

    import yaml

    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "config.yaml").write_text(yaml.safe_dump(base_study))
    report = ("--report", "results/analytic/report.html")

    def said() -> str:
        proc = smk(tmp_path, *report, check=False, timeout=120)
        assert proc.returncode != 0
        assert not (tmp_path / "results" / "analytic" / "report.html").exists()
        out = proc.stdout + proc.stderr
        assert "does not exist." not in out and "WorkflowError" not in out, out[-2000:]
        return out

    assert "bayescalib: no report: study 'analytic' has no results yet" in (out := said())
    assert "it has not been run" in out and "snakemake --cores 2;" in out
    (tmp_path / "results" / "analytic" / "runs").mkdir(parents=True)  # an interrupted run
    out = said()
    assert "its run has not finished (interrupted or failed)" in out
    assert "then make the report: snakemake --report results/analytic/report.html" in out
    live = subprocess.Popen(
        [sys.executable, "-c", ("from bayescalib.study import hold_run_lock; "
         f"hold_run_lock({str(tmp_path / 'results' / 'analytic')!r}, 'analytic'); "
         "print('held', flush=True); import time; time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert live.stdout.readline().strip() == "held"
        out = said()
    finally:
        live.kill()
        live.wait()
    assert f"study 'analytic' is being run right now (snakemake pid {live.pid}" in out
    assert "Wait for the run to end, then run: snakemake --report" in out
