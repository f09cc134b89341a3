"""Export: slide-ready SVG/PNG/PDF through kaleido + Debian's chromium, the slide pack ZIP,
`python -m ifo export`, and what happens on a machine without Chromium.

One small real CartPole run (two iterations) is trained once for the whole module.
"""
import csv
import io
import json
import re
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import plotly.graph_objects as go
import pytest
from streamlit.testing.v1 import AppTest

from ifo import checkpoint, export
from ifo.cli import main
from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.run import Run

needs_chromium = pytest.mark.skipif(export.find_chromium() is None, reason="no Chromium on this machine")
# the figure registry's choice for BCO(α)'s records, as on the step page, plus where the time goes
BCO_ALPHA_FIGURES = ["aer", "performance", "idm", "idm_over_time", "idm_confusion", "idm_confidence", "accuracy",
                     "sampling", "sampling_share", "win", "phase_seconds"]


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    run = Run(RunConfig.from_dict(dict(env="cartpole", method="bco-alpha", iterations=2, pre_size=2000,
                                       episodes_per_iteration=10, eval_episodes=10, policy_epochs=2,
                                       expert_episodes=2)))
    run.run()
    directory = run.save(tmp_path_factory.mktemp("export") / "run")
    return run, directory


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def check_svg(data: bytes) -> None:
    root = ET.fromstring(data)
    assert root.tag.rsplit("}", 1)[-1] == "svg"


# ----------------------------------------------------------------------------- library
def test_run_figures_lists_every_figure_that_applies_in_the_slide_theme(saved_run):
    run, _ = saved_run
    figs = export.run_figures(run.records, run.config.to_dict())
    assert list(figs) == BCO_ALPHA_FIGURES
    for fig in figs.values():
        assert isinstance(fig, go.Figure)
        assert (fig.layout.width, fig.layout.height) == (1600, 900) and fig.layout.font.size >= 20
    assert export.run_figures([], run.config.to_dict()) == {}
    screen = export.run_figures(run.records, run.config.to_dict(), theme="screen")
    assert list(screen) == BCO_ALPHA_FIGURES and screen["aer"].layout.width is None


def test_run_figures_adds_attention_figures_only_when_records_have_them(saved_run):
    run, _ = saved_run
    records = json.loads(json.dumps(run.records))
    records[-1]["policy"]["attention"] = [0.4, 0.2, 0.2, 0.2]
    records[-1]["attention"] = {"grad_cam": {"maps": [[[0.0, 1.0], [0.5, 0.2]]], "actions": [1],
                                             "probabilities": [[0.3, 0.7]]}}
    figs = export.run_figures(records, run.config.to_dict())
    assert {"state_attention", "grad_cam"} <= set(figs) and "action_distance" not in figs
    assert list(figs["state_attention"].data[0].x) == list(get_env("cartpole").feature_names)


def test_slide_theme_copy_leaves_the_screen_figure_alone():
    fig = go.Figure(go.Scatter(x=[1, 2], y=[3, 4]))
    slide = export.slide_theme(fig)
    assert (slide.layout.width, slide.layout.height) == (1600, 900) and slide.layout.font.size == 22
    assert fig.layout.width is None and fig.layout.font.size is None


@needs_chromium
def test_svg_png_pdf_bytes(saved_run):
    run, _ = saved_run
    fig = export.run_figures(run.records, run.config.to_dict())["aer"]
    check_svg(export.figure_bytes(fig, "svg"))
    width, height = png_size(export.figure_bytes(fig, "png"))
    assert width >= 1600 and width * 9 == height * 16  # high resolution, 16:9
    assert export.figure_bytes(fig, "pdf").startswith(b"%PDF")
    with pytest.raises(ValueError, match="format must be one of"):
        export.figure_bytes(fig, "gif")


def test_metrics_csv_has_one_row_per_iteration(saved_run):
    run, _ = saved_run
    rows = list(csv.DictReader(io.StringIO(export.metrics_csv(run.records))))
    assert len(rows) == 2 and list(rows[0]) == export.metric_columns(run.records)
    for row, rec in zip(rows, run.records):
        assert int(row["iteration"]) == rec["iteration"]
        assert float(row["evaluation.aer"]) == pytest.approx(rec["evaluation"]["aer"], rel=1e-5)
        assert float(row["idm.val_accuracy"]) == pytest.approx(rec["idm"]["val_accuracy"], rel=1e-5)
        assert float(row["rollouts.win_probability"]) == pytest.approx(rec["rollouts"]["win_probability"], rel=1e-5)
        assert int(row["sampling.size"]) == rec["sampling"]["size"]
        assert float(row["sampling.realised_share"]) == pytest.approx(rec["sampling"]["realised_share"], rel=1e-5)
        assert float(row["seconds.total"]) == pytest.approx(rec["seconds"]["total"], rel=1e-5)
    # the columns follow the sections a method's records have: a TD section brings its own
    records = [{"iteration": 1, "policy": {"agreement": 1.0}, "evaluation": {"aer": 9.0, "aer_std": 1.0}},
               {"iteration": 2, "td": {"loss": 0.5, "epsilon": 0.1}, "evaluation": {"aer": 10.0, "aer_std": 1.0}}]
    rows = list(csv.DictReader(io.StringIO(export.metrics_csv(records))))
    assert rows[0]["evaluation.aer"] == "9" and rows[0]["td.epsilon"] == "" and rows[1]["td.epsilon"] == "0.1"
    assert "idm.val_accuracy" not in rows[0]


@needs_chromium
def test_slide_pack_zip(saved_run):
    run, _ = saved_run
    config = run.config.to_dict()
    data = export.slide_pack(run.records, config)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        names = set(z.namelist())
        expected = {f"figures/{n}.{f}" for n in BCO_ALPHA_FIGURES for f in ("svg", "png", "pdf")}
        assert names == expected | {"metrics.csv", "config.json", "README.txt"}
        check_svg(z.read("figures/accuracy.svg"))
        assert png_size(z.read("figures/aer.png"))[0] >= 1600
        assert z.read("figures/phase_seconds.pdf").startswith(b"%PDF")
        assert z.read("metrics.csv").decode() == export.metrics_csv(run.records)
        back = json.loads(z.read("config.json"))
        assert back == config and RunConfig.from_dict(back) == run.config
        readme = z.read("README.txt").decode()
        assert "python -m ifo export" in readme and "metrics.csv" in readme and "figures/aer.{svg,png,pdf}" in readme


def test_a_pack_without_formats_needs_no_browser(saved_run, monkeypatch):
    run, _ = saved_run
    monkeypatch.setattr(export, "find_chromium", lambda: None)
    with zipfile.ZipFile(io.BytesIO(export.slide_pack(run.records, run.config.to_dict(),
                                                      formats=()))) as z:
        assert set(z.namelist()) == {"metrics.csv", "config.json", "README.txt"}


# ----------------------------------------------------------------------------- command line
@needs_chromium
def test_cli_export_writes_the_files(saved_run, tmp_path, capsys):
    _, directory = saved_run
    out = tmp_path / "slides"
    assert main(["export", str(directory), "--out", str(out), "--formats", "svg"]) == 0
    printed = capsys.readouterr().out.split()
    expected = [out / "figures" / f"{n}.svg" for n in BCO_ALPHA_FIGURES]
    expected += [out / "metrics.csv", out / "config.json", out / "README.txt"]
    assert sorted(printed) == sorted(map(str, expected))
    assert all(p.is_file() and p.stat().st_size > 0 for p in expected)
    assert not list(out.rglob("*.png")) and not list(out.rglob("*.pdf")) and not list(out.rglob("*.tmp"))
    assert len((out / "metrics.csv").read_text().splitlines()) == 3  # header + 2 iterations

    assert main(["export", str(directory), "--out", str(out), "--formats", "pdf", "--zip"]) == 0
    (zip_path,) = capsys.readouterr().out.split()
    assert zip_path == str(out / "run-slides.zip")
    with zipfile.ZipFile(zip_path) as z:
        assert "figures/aer.pdf" in z.namelist() and "figures/aer.svg" not in z.namelist()
        assert {"metrics.csv", "config.json", "README.txt"} <= set(z.namelist())


def test_cli_missing_run_is_one_clear_line_and_exit_2(tmp_path):
    res = subprocess.run([sys.executable, "-m", "ifo", "export", str(tmp_path / "nope"), "--out", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr.strip() == f"error: no run folder {tmp_path / 'nope'}"
    assert not (tmp_path / "o").exists()


def test_cli_bad_input_exit_2(saved_run, tmp_path, capsys):
    _, directory = saved_run
    assert main(["export", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "holds no saved run" in capsys.readouterr().err
    assert main(["export", str(directory), "--out", str(tmp_path / "o"), "--formats", "svg,gif"]) == 2
    assert "--formats must be" in capsys.readouterr().err


def _edited_run(saved_run, path, *, records=None, config=None):
    """A run folder holding the saved run's records/config as edited (ifo.checkpoint writes it)."""
    run, _ = saved_run
    records = json.loads(json.dumps(run.records)) if records is None else records
    checkpoint.save(path, config=run.config.to_dict() if config is None else config, records=records,
                    arrays={}, meta={"iteration": len(records)}, parent=None)
    return path


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("edit, message", [
    (lambda r: r.pop("evaluation"), "record 2 of 2 lacks evaluation;"),
    (lambda r: r["evaluation"].pop("aer"), "record 2 of 2 lacks evaluation.aer;"),
    (lambda r: r.pop("seconds"), "record 2 of 2 lacks seconds;"),
    (lambda r: r.update(evaluation=[1, 2]), "record 2 of 2 lacks evaluation (not a mapping)"),
])
def test_records_that_lack_a_field_give_one_clear_error(saved_run, tmp_path, capsys, edit, message):
    run, _ = saved_run
    records = json.loads(json.dumps(run.records))
    edit(records[-1])
    path = _edited_run(saved_run, tmp_path / "edited", records=records)
    with pytest.raises(ValueError, match=re.escape(message)):
        export.load_run_files(path)
    with pytest.raises(ValueError, match=re.escape(message)):
        export.export_run(path, tmp_path / "out", formats=["svg"])
    assert main(["export", str(path), "--out", str(tmp_path / "o"), "--formats", "svg"]) == 2
    assert message in one_error_line(capsys)
    assert not (tmp_path / "o").exists() and not (tmp_path / "out").exists()


def test_a_config_without_env_a_damaged_run_and_out_under_a_file_give_clear_errors(saved_run, tmp_path, capsys):
    run, directory = saved_run
    config = run.config.to_dict()
    del config["env"]
    no_env = _edited_run(saved_run, tmp_path / "no-env", config=config)
    with pytest.raises(ValueError, match=r"the saved configuration names no environment \('env'\)"):
        export.load_run_files(no_env)
    assert main(["export", str(no_env), "--out", str(tmp_path / "o")]) == 2
    assert "names no environment" in one_error_line(capsys)

    damaged = _edited_run(saved_run, tmp_path / "damaged")
    (damaged / "LATEST").write_text("/etc")
    with pytest.raises(checkpoint.DamagedRun, match="LATEST does not name a checkpoint of this folder"):
        export.load_run_files(damaged)
    assert main(["export", str(damaged), "--out", str(tmp_path / "o")]) == 2
    assert "LATEST does not name a checkpoint" in one_error_line(capsys)

    (tmp_path / "a-file").write_text("x")
    with pytest.raises(ValueError, match=r"--out .*a-file/slides lies under .*a-file, which is a file, not a folder"):
        export.export_run(directory, tmp_path / "a-file" / "slides", formats=["svg"])
    with pytest.raises(ValueError, match=r"--out .*a-file is a file, not a folder"):
        export.export_run(directory, tmp_path / "a-file", formats=["svg"], as_zip=True)
    assert main(["export", str(directory), "--out", str(tmp_path / "a-file" / "slides"), "--formats", "svg"]) == 2
    assert "lies under" in one_error_line(capsys)
    assert (tmp_path / "a-file").read_text() == "x"


# ----------------------------------------------------------------------------- no Chromium
def test_no_chromium_raises_export_unavailable_with_the_fix(saved_run, monkeypatch, tmp_path, capsys):
    run, directory = saved_run
    missing = str(tmp_path / "no-such-browser")
    monkeypatch.setenv("BROWSER_PATH", missing)
    assert export.find_chromium() != missing  # a wrong BROWSER_PATH is skipped, not trusted
    monkeypatch.setattr(export, "find_chromium", lambda: None)  # and no chromium anywhere
    fig = export.run_figures(run.records, run.config.to_dict())["aer"]
    with pytest.raises(export.ExportUnavailable) as err:
        export.figure_bytes(fig, "svg")
    message = str(err.value)
    assert message.startswith("No Chromium found: install Debian's chromium package (apt-get install chromium) "
                              "or set BROWSER_PATH; the chart's camera button still downloads PNG/SVG")
    assert missing in message  # says the BROWSER_PATH it was given is wrong
    assert export.export_problem() == message
    with pytest.raises(export.ExportUnavailable):
        export.slide_pack(run.records, run.config.to_dict())
    assert main(["export", str(directory), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.startswith("error: No Chromium found")
    assert not (tmp_path / "o").exists()


def _downloads_app():
    import plotly.graph_objects as go
    import streamlit as st
    from streamlit import runtime

    from ifo.ui.export import chart_downloads, slide_pack_download

    records = st.session_state.get("records", [])
    chart_downloads(go.Figure(go.Scatter(x=[1, 2], y=[3, 4])), "learning curve", key="aer.dl")
    slide_pack_download(records, {"env": "cartpole", "method": "bco-alpha", "seed": 0},
                        key="pack")
    st.session_state["media"] = runtime.get_instance().media_file_mgr  # to click a deferred download


def downloads(at: AppTest) -> dict[str, object]:
    return {b.proto.label: b.proto for b in at.get("download_button")}


def test_ui_without_chromium_shows_one_note_and_no_crash(monkeypatch, saved_run):
    run, _ = saved_run
    monkeypatch.setenv("BROWSER_PATH", "/nonexistent/chromium")
    monkeypatch.setattr(export, "find_chromium", lambda: None)
    at = AppTest.from_function(_downloads_app, default_timeout=60)
    at.session_state["records"] = run.records
    at.run()
    assert not at.exception
    infos = [i.value for i in at.info]
    assert len(infos) == 2 and all(i.startswith("No Chromium found") for i in infos)  # chart, slide pack
    assert "camera button" in infos[0]
    assert list(downloads(at)) == ["Metrics and configuration (ZIP)"]  # still something to take away


@needs_chromium
def test_ui_downloads_render_only_when_clicked(monkeypatch):
    calls = []
    real = export.figure_bytes
    monkeypatch.setattr(export, "figure_bytes", lambda fig, fmt, **kw: calls.append(fmt) or real(fig, fmt, **kw))
    at = AppTest.from_function(_downloads_app, default_timeout=60).run()
    at.run()  # a rerun renders nothing either
    assert not at.exception and not at.info and calls == []
    buttons = downloads(at)
    assert list(buttons) == ["SVG", "PNG", "PDF", "Slide pack (ZIP)"]
    assert buttons["Slide pack (ZIP)"].disabled  # no iterations yet
    assert buttons["PNG"].deferred_file_id and not buttons["PNG"].url

    media = at.session_state["media"]
    url = media.execute_deferred(buttons["PNG"].deferred_file_id)  # what a click does
    stored = media._storage.get_file(Path(url).stem)
    assert calls == ["png"] and stored.filename == "learning-curve.png" and stored.mimetype == "image/png"
    assert png_size(stored.content) == (3200, 1800)  # the slide theme at twice the size


# ----------------------------------------------------------------------------- a browser that will not start
def test_a_browser_that_will_not_start_gives_export_unavailable(monkeypatch, tmp_path):
    fake = tmp_path / "fake-chromium"
    fake.write_text("#!/bin/sh\nexit 1\n")
    fake.chmod(0o755)
    monkeypatch.setenv("BROWSER_PATH", str(fake))
    assert export.find_chromium() == str(fake)  # BROWSER_PATH comes first
    try:
        with pytest.raises(export.ExportUnavailable, match="would not start"):
            export.figure_bytes(go.Figure(), "svg")
        assert "would not start" in export.export_problem()
        with pytest.raises(export.ExportUnavailable):  # remembered: no second wait
            export.figure_bytes(go.Figure(), "svg")
    finally:
        export.shutdown()
    assert export.export_problem() is None
