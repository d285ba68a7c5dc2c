"""The report stands alone: the petal build's page is parsed for its provenance, STL list,
fabrication sheet and captions; its plot titles fit; its embedded 3D viewer draws in a real
headless chromium from ``file://`` (offline); the stretch template is 1:1 and exact.
"""

from __future__ import annotations

import json
import math
import re
from html.parser import HTMLParser

import numpy as np
import pytest
from _browser import chrome, have_browser

from pysolver.core.provenance import sha256_file
from pysolver.params import FABRICATION, SIM
from pysolver.tables import read_table
from sim.report import fabrication as fab


class _Page(HTMLParser):
    """Sections, figure captions, table rows (per section) and scripts of a report page."""

    def __init__(self):
        super().__init__()
        self.section = None
        self.sections = []
        self.captions = []
        self.rows: dict[str, list[list[str]]] = {}
        self._cell = None
        self._row = None
        self._cap = None
        self.scripts_with_src = 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "section":
            self.section = a.get("id")
            self.sections.append(self.section)
        elif tag == "figcaption":
            self._cap = ""
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._cell = ""
        elif tag == "script" and a.get("src"):
            self.scripts_with_src += 1

    def handle_endtag(self, tag):
        if tag == "figcaption" and self._cap is not None:
            self.captions.append(self._cap.strip())
            self._cap = None
        elif tag in ("td", "th") and self._cell is not None:
            self._row.append(self._cell.strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.rows.setdefault(self.section, []).append(self._row)
            self._row = None

    def handle_data(self, data):
        if self._cap is not None:
            self._cap += data
        if self._cell is not None:
            self._cell += data


@pytest.fixture(scope="module")
def petal(tmp_path_factory):
    from pysolver.build import build

    out = tmp_path_factory.mktemp("standalone") / "petal"
    build("petal", out=out, refine=0, progress=False)
    return out


@pytest.fixture(scope="module")
def page(petal):
    p = _Page()
    p.feed((petal / "report" / "index.html").read_text(encoding="utf-8"))
    return p


def test_one_caption_each_and_every_section(page):
    from sim.report import SECTIONS

    assert page.sections == list(SECTIONS)
    assert len(page.captions) >= 10
    dup = {c for c in page.captions if page.captions.count(c) > 1}
    assert not dup, f"duplicated captions: {dup}"
    assert page.scripts_with_src == 0          # everything inline: opens offline, mailable


def test_provenance_lists_input_options_models_versions(page, petal):
    rows = {r[0]: r[1] for r in page.rows["provenance"] if len(r) == 2}
    design = json.loads((petal / "design.json").read_text())["options"]
    assert rows["input"] == "petal (builtin)"
    assert rows["input sha256"] == design["source_sha256_16"]
    source = json.loads((petal / "design.json").read_text())["summary"]["time"]["source"]
    assert rows["time landscape"].startswith(source)  # as design recorded it: "shape default"
    assert rows["refinement rounds"] == "0"
    for k in ("vertices", "time", "scale", "flattening", "refine", "material", "t_end"):
        assert f"option {k}" in rows, k
    temporal = json.loads((petal / "temporal.json").read_text())["summary"]
    mat = temporal["material_model"]
    assert rows["material (bracket) model"].startswith(mat)
    assert sha256_file(mat) in rows["material (bracket) model"]
    assert re.search(r"sha256 [0-9a-f]{64}", rows["membrane model"])
    assert "morphshell 0.1.0" in rows["versions"] and "numpy" in rows["versions"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC", rows["report date"])
    js = json.loads((petal / "report" / "report.json").read_text())
    assert js["provenance"]["build_inputs_sha256"] == rows["build inputs sha256"]
    assert len(rows["build inputs sha256"]) == 64


def test_stl_list_names_every_stl_with_size_and_purpose(page, petal):
    rows = page.rows["stls"][1:]                      # after the header row
    files = sorted((petal / "stl").glob("*.stl"))
    assert [r[0] for r in rows] == [f"stl/{p.name}" for p in files]
    assert {p.name for p in files} >= {"top.stl", "bottom.stl", "markers_top.stl",
                                       "support_frame_top.stl", "actuated.stl"}
    for r, p in zip(rows, files, strict=True):
        size = p.stat().st_size
        shown = float(r[1].split()[0]) * (1e6 if r[1].endswith("MB") else 1e3)
        assert abs(shown - size) <= 0.01 * size
        assert int(r[2]) == (size - 84) // 50       # binary STL: 50 bytes per triangle
        assert r[4] == fab.STL_PURPOSE[p.name]


def test_fabrication_sheet_follows_note_5(petal):
    text = (petal / "report" / "index.html").read_text(encoding="utf-8")
    sec = text[text.index("<section id='fabrication'>"):text.index("<section id='stls'>")]
    align = np.flatnonzero(read_table(petal, "bases")["alignment"]).tolist()
    assert f"bases {', '.join(map(str, align))}" in sec
    assert f"{len(align)} alignment holes" in sec
    for needle in (f"{FABRICATION.water_c:g} °C", f"stretch of {SIM.tau:g}x",
                   f"near {FABRICATION.release_stretch:g}x", f"Ø {FABRICATION.pin_diameter_mm:g}"
                   " mm", "stl/top.stl", "stl/bottom.stl", "stretch_template.svg",
                   "2-propanol"):
        assert needle in sec, needle
    js = json.loads((petal / "report" / "report.json").read_text())
    tl = js["fabrication"]["timeline"]
    assert sum(g["cells"] for g in tl) == len(read_table(petal, "cells")["cell_id"])


def test_plot_titles_fit(petal, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from sim.report import make_report
    from sim.report import plots as rp

    checked = []
    real = rp._save

    def save(fig, path):
        rp.fit_titles(fig)
        checked.append((path.name, rp.titles_fit(fig)))
        return real(fig, path)

    monkeypatch.setattr(rp, "_save", save)
    make_report(petal, out_dir=tmp_path / "report", progress=False, image_px=200)
    assert len(checked) >= 6
    assert all(ok for _, ok in checked), checked
    # and the fit is real: a title twice the figure's width is cut before, fits after
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.set_title("a very long title that says everything about the plot " * 3)
    assert not rp.titles_fit(fig)
    assert rp.fit_titles(fig) > 0 and rp.titles_fit(fig)
    plt.close(fig)


def test_stretch_template_is_exact_and_1_to_1(tmp_path):
    ang = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    circle = np.c_[50 * np.cos(ang), 50 * np.sin(ang)] + [7.0, -3.0]
    tp = fab.stretch_template(circle, tau=3.0)
    # the smallest device that holds the cut line plus the wrap: 2 (50 + 3 + 15) <= 200
    assert tp["device_d_mm"] == 200.0 and tp["fits"]
    r = np.linalg.norm(tp["markers"], axis=1)
    assert np.allclose(r, 200.0 / 6) and len(r) == FABRICATION.star_teeth
    assert np.linalg.norm(tp["outline"], axis=1).max() == pytest.approx(50 / 3, rel=1e-9)
    cut_r = np.linalg.norm(tp["cut"], axis=1)
    assert cut_r.max() == pytest.approx(53 / 3, rel=2e-3)
    assert cut_r.min() == pytest.approx(53 / 3, rel=2e-2)
    svg = fab.template_svg(tp, "t")
    w = float(re.search(r'width="([\d.]+)mm"', svg).group(1))
    vb = [float(x) for x in re.search(r'viewBox="([^"]+)"', svg).group(1).split()]
    assert vb[2] == pytest.approx(w, abs=1e-2)       # 1 user unit = 1 mm
    dots = re.findall(r'class="marker" data-i="\d+" cx="([\d.]+)" cy="([\d.]+)"', svg)
    c = vb[2] / 2
    assert len(dots) == FABRICATION.star_teeth
    assert all(math.isclose(math.hypot(float(x) - c, float(y) - c), 200 / 6, abs_tol=3e-3)
               for x, y in dots)
    pdf = fab.template_pdf(tp, tmp_path / "t.pdf", "t").read_bytes()
    box = [float(x) for x in re.search(rb"/MediaBox \[ *([\d. ]+)\]", pdf).group(1).split()]
    assert box[2] - box[0] == pytest.approx(tp["sheet_mm"] * 72 / 25.4, abs=0.01)   # 1:1
    big = fab.stretch_template(circle * 10, tau=3.0)   # 500 mm shell: no device is big enough
    assert not big["fits"] and big["device_d_mm"] == max(FABRICATION.star_diameters_mm)


def test_viewer_data_round_trips(petal):
    """The viewer's JSON decodes to the frames, each aligned rigidly to the target."""
    import base64

    from sim.model.collisions import completion_times
    from sim.report import load_sim
    from sim.viewer import frame_alignments, viewer_data

    sd = load_sim(petal)
    fr = sd.frames
    t_done = completion_times(fr)
    v = viewer_data(sd, t_done, max_frames=30)
    sel = np.asarray(v["frames"])
    assert len(sel) == 30 and sel[0] == 0 and sel[-1] == len(fr["t"]) - 1
    c = v["center"]
    q = np.frombuffer(base64.b64decode(c["data"]), "<u2").reshape(30, sd.n_bases, 3)
    C = np.asarray(c["lo"]) + q / 65535.0 * np.asarray(c["span"])
    Q, s = frame_alignments(fr["base_center"][sel], sd.target)
    want = np.einsum("fij,fbj->fbi", Q, fr["base_center"][sel]) + s[:, None]
    assert np.abs(C - want).max() <= 0.51 * max(c["span"]) / 65535 + 1e-9
    # the last frame's distances are the report's shape error
    dist = np.frombuffer(base64.b64decode(v["distance"]), "<f4").reshape(30, sd.n_bases)
    js = json.loads((petal / "report" / "report.json").read_text())
    assert float(np.sqrt(np.mean(dist[-1].astype(float) ** 2))) == pytest.approx(
        js["metrics"]["shape"]["rms_mm"], rel=1e-5)
    assert len(v["base_fields"]["completion"]) == sd.n_bases
    assert v["cells"]["clamped"] == np.asarray(sd.cells["clamped"], int).tolist()


@pytest.mark.skipif(not have_browser(), reason="Debian chromium + chromium-driver not installed")
def test_embedded_viewer_draws_offline_from_file(petal):
    from selenium.webdriver.support.ui import WebDriverWait

    with chrome(1200, 900) as d:
        d.get((petal / "report" / "index.html").as_uri())
        WebDriverWait(d, 90, poll_frequency=0.2).until(
            lambda d: d.execute_script("return !!(window.morphViewer && "
                                       "window.morphViewer.renderCount > 0)"))
        first = d.execute_script("return window.morphViewer.pixelStats()")
        assert first["ink"] > 0.02
        nf = d.execute_script("return window.morphViewer.nf")
        d.execute_script("window.morphViewer.setFrame(arguments[0])", nf - 1)
        WebDriverWait(d, 90, poll_frequency=0.2).until(
            lambda d: d.find_element("id", "morph-viewer").get_attribute("data-frame")
            == str(nf - 1))
        last = d.execute_script("return window.morphViewer.pixelStats()")
        assert last["checksum"] != first["checksum"]
        # completion colours: one value per base, as many as bases.csv rows
        n = d.execute_script("return window.morphViewer.fieldValues().length")
        assert n == len(read_table(petal, "bases")["base_id"])
