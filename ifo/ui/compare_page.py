"""What the compare page and the run list share: configurations to queue, the thesis's numbers
for a configuration, the summary table in the thesis's layout, and the queue panel.

Pure helpers first (no streamlit; tested directly), then the drawing functions.
"""
from __future__ import annotations

from dataclasses import dataclass

from ifo.config import RunConfig, configuration_label, switches
from ifo.envs import get_env
from ifo.methods import get_method
from ifo.reproduce import TABLES, implemented, mean_sd, number
from ifo.ui.settings import fast_overrides

PRESET_TABLES = ("5.2", "6.2")


@dataclass(frozen=True)
class Planned:
    """One configuration to queue: its group label (rows of the summary) and its config per seed."""

    group: str
    config: RunConfig  # seed filled in per job
    thesis: tuple | None  # (P, AER, source) or None


def env_title(env: str) -> str:
    spec = get_env(env)
    return spec.thesis_name or spec.name


def _kind(config: RunConfig) -> tuple:
    """What makes two configurations the same experiment for the thesis tables."""
    cfg = config.resolved()
    method = get_method(cfg.method)
    return (method.learner, method.sees_expert_actions, method.fixed_iterations, tuple(sorted(switches(cfg).items())))


def thesis_numbers(config: RunConfig) -> tuple | None:
    """(P, AER, "Table x.y: row") the thesis reports for this configuration on its environment, or None."""
    env = get_env(config.env).name
    kind = _kind(config)
    for table_id in ("6.1", "5.1", "5.2", "6.2", "9.1", "8.4"):
        table = TABLES[table_id]
        if env not in table.envs:
            continue
        for row in table.rows:
            if row.method in ("expert", "random") or not implemented(row) or row.runner is not None:
                continue
            if _kind(RunConfig.from_dict({"env": env, "method": row.method, **row.overrides})) != kind:
                continue
            values = table.thesis.get(row.label, {}).get(env)
            if values is not None and any(v is not None for v in values):
                return (values[0], values[1], f"Table {table_id}: {row.label}")
    return None


def group_label(name: str, config: RunConfig) -> str:
    cfg = config.resolved()
    label = f"{name} · {env_title(cfg.env)}"
    default = RunConfig(env=cfg.env, method=cfg.method).resolved().iterations
    if cfg.iterations != default:
        label += f" · {cfg.iterations} it."
    if cfg.demos:
        label += " · your demos"
    return label


def plan(config: RunConfig, name: str | None = None, thesis: tuple | None = None) -> Planned:
    config = RunConfig.from_dict({**config.to_dict(), **fast_overrides(config.method)}).resolved()
    name = name or configuration_label(config)
    if thesis is None and not config.demos:
        thesis = thesis_numbers(config)
    return Planned(group_label(name, config), config, thesis)


def method_configs(env: str, methods: list[str], iterations: int | None = None,
                   demos: dict | None = None) -> list[Planned]:
    """Each method on `env`; `demos`: the settings of a user's demonstrations (`storage.demos_settings`)."""
    return [plan(RunConfig.from_dict({"env": env, "method": m, **(demos or {}),
                                      "iterations": iterations if get_method(m).fixed_iterations is None else None}))
            for m in methods]


def switch_config(env: str, attention: bool, sampling: str, exploration: bool,
                  iterations: int | None = None, demos: dict | None = None) -> Planned:
    """The one loop (BCO(α)) with the thesis's ablation switches set by hand."""
    return plan(RunConfig.from_dict(dict(env=env, method="bco-alpha", iterations=iterations,
                                         attention="gated" if attention else "none", sampling=sampling,
                                         explore_labels=exploration, explore_rollouts=exploration, **(demos or {}))))


def preset_configs(table_id: str, env: str | None = None, iterations: int | None = None,
                   demos: dict | None = None) -> list[Planned]:
    """Every row of an ablation table (5.2 or 6.2) as a configuration, on the table's maze or `env`."""
    table = TABLES[table_id]
    env = get_env(env or table.envs[0]).name
    out = []
    for row in table.rows:
        # the row's own table first: the thesis's tables do not always agree (BCO(α) on the 5×5
        # maze has AER 0.104 in Table 5.1 but -0.941 in Table 5.2)
        own = table.thesis.get(row.label, {}).get(env)
        thesis = (*own, f"Table {table_id}: {row.label}") if own else None
        out.append(plan(RunConfig.from_dict({"env": env, "method": row.method, "iterations": iterations,
                                             **row.overrides, **(demos or {})}), row.label, thesis))
    return out


def distinct_labels(runs: list[tuple[str, list]]) -> list[tuple[str, list]]:
    """Runs with the same name (two copies of one example, say) get " (2)", " (3)"... so every curve
    and legend entry can be told apart."""
    seen: dict[str, int] = {}
    out = []
    for label, records in runs:
        seen[label] = seen.get(label, 0) + 1
        out.append((label if seen[label] == 1 else f"{label} ({seen[label]})", records))
    return out


def common_references(entries: list[dict]) -> dict | None:
    """The expert's and a random policy's AER when every entry is on one environment and measured its
    Performance against the same ones (its records say which: a user's demonstrations are their own
    expert), else None. Records from before they held their references: the environment's."""
    envs = {e.get("env") for e in entries}
    if len(envs) != 1 or None in envs:
        return None
    measured = {(ev.get("expert_reference"), ev.get("random_reference"))
                for ev in ((e.get("records") or [{}])[-1].get("evaluation") or {} for e in entries)}
    if measured != {(None, None)}:
        if len(measured) != 1:
            return None  # runs on different demonstrators: no one line fits them all
        expert, random = measured.pop()
        return {"expert": expert, "random": random}
    refs = get_env(envs.pop()).references()
    return {"expert": refs.get("expert_aer"), "random": refs.get("random_aer")}


def compare_pack(runs: list[tuple[str, list]], rows: list[dict], references: dict | None, formats=("svg", "png", "pdf"),
                 ) -> bytes:
    """The comparison as a slide pack: both curves as SVG/PNG/PDF (slide theme), summary.csv, metrics per run."""
    import csv
    import io
    import zipfile

    from ifo import export, figures

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for metric in ("performance", "aer"):
            fig = figures.compare_runs(runs, metric, "slide", references=references)
            for fmt in formats:
                z.writestr(f"figures/compare-{metric}.{fmt}", export.figure_bytes(fig, fmt))
        table = io.StringIO()
        if rows:
            w = csv.DictWriter(table, fieldnames=list(rows[0]), lineterminator="\n")
            w.writeheader()
            w.writerows(rows)
        z.writestr("summary.csv", table.getvalue())
        for label, records in runs:
            name = "".join(c if c.isalnum() or c in "-_." else "-" for c in label)[:80]
            z.writestr(f"runs/{name}.csv", export.metrics_csv(records))
    return buf.getvalue()


def summary_rows(entries: list[dict]) -> list[dict]:
    """The thesis's layout: one row per configuration, P and AER ours (mean ± sd over its seeds, at
    each seed's latest iteration) beside the thesis's numbers.

    `entries`: dicts with group, records, total (iterations), state, thesis (or None)."""
    groups: dict[str, list[dict]] = {}
    for e in entries:
        groups.setdefault(e["group"], []).append(e)
    rows = []
    for group, members in groups.items():
        lasts = [m["records"][-1]["evaluation"] for m in members if m["records"]]
        finished = sum(1 for m in members if m["records"] and len(m["records"]) >= m["total"])
        thesis = next((m["thesis"] for m in members if m.get("thesis")), None)
        failed = sum(1 for m in members if m.get("state") == "error")
        status = f"{finished}/{len(members)} finished" + (f", {failed} failed" if failed else "")
        its = sorted({len(m["records"]) for m in members if m["records"]})
        rows.append({
            "configuration": group,
            "seeds": status,
            "iteration": "—" if not its else (str(its[0]) if len(its) == 1 else f"{its[0]}–{its[-1]}"),
            "P (ours)": mean_sd([ev.get("performance") for ev in lasts]),
            "P (thesis)": number(thesis[0]) if thesis else "—",
            "AER (ours)": mean_sd([ev.get("aer") for ev in lasts]),
            "AER (thesis)": number(thesis[1]) if thesis else "—",
            "thesis source": thesis[2] if thesis and len(thesis) > 2 else "",
        })
    return rows


# ----------------------------------------------------------------------------- drawing
STATE_TEXT = {"queued": "waiting", "running": "training", "done": "finished", "error": "failed",
              "cancelled": "cancelled"}
REFRESH_SECONDS = 2.0


def queue_jobs(planned: list[Planned], seeds: int, user: str, queue) -> int:
    """Queue every planned configuration once per seed 0..seeds-1; returns how many jobs were queued."""
    from dataclasses import replace

    n = 0
    for p in planned:
        for seed in range(seeds):
            queue.submit(user, replace(p.config, seed=seed), label=f"{p.group}, seed {seed}", group=p.group,
                         thesis=p.thesis)
            n += 1
    return n


def compare_pack_download(runs, rows, references, key: str) -> None:
    import streamlit as st

    from ifo import export

    problem = export.export_problem()
    formats = () if problem else ("svg", "png", "pdf")
    if problem:
        st.info(f"{problem}. The download below holds the tables only.", icon=":material/info:")
    st.download_button("Comparison slide pack (ZIP)" if formats else "Comparison tables (ZIP)",
                       data=lambda: compare_pack(runs, rows, references, formats), file_name="comparison.zip",
                       mime="application/zip", key=key, on_click="ignore", icon=":material/folder_zip:",
                       help="Both charts (16:9, large fonts) as SVG, PNG and PDF, the summary table and each run's "
                            "metrics as CSV.")


def job_line(job) -> str:
    state = STATE_TEXT.get(job.state, job.state)
    if job.state == "queued":
        state += f" (position {job.position} in the queue)"
    elif job.state == "running":
        state += f": iteration {job.iteration + 1} of {job.total}" + (f", {job.phase}" if job.phase else "")
    elif job.state in ("done", "cancelled"):
        state += f" after {job.iteration} of {job.total} iterations"
    if job.records:
        ev = job.records[-1]["evaluation"]
        perf = ev.get("performance")
        state += f" · AER {ev['aer']:.2f}" + ("" if perf is None else f" · P {perf:.2f}")
    return f"**{job.label}**: {state}"


def queue_panel(user: str, queue, key: str, show_results: bool = True, extra_runs: list | None = None) -> None:
    """The user's queued jobs with progress and cancel buttons, then (optionally) their curves and the
    summary table. Call it inside a fragment that reruns every REFRESH_SECONDS while jobs are active."""
    import streamlit as st

    from ifo import figures
    from ifo.ui.export import chart_downloads
    from ifo.ui.panels import CHART_CONFIG

    jobs = queue.jobs(user)
    if not jobs and not extra_runs:
        st.info("Nothing queued yet: add configurations above.")
        return
    if jobs:
        active = [j for j in jobs if j.active]
        st.markdown(f"**Queue:** {len(active)} waiting or training, {len(jobs) - len(active)} ended. "
                    "Runs train one after another in the background (you may close this tab); "
                    "each is saved after every iteration to *Your runs*.")
        for job in jobs:
            text, button = st.columns([6, 1], vertical_alignment="center")
            with text:
                st.markdown(job_line(job))
                if job.state == "running" and job.total:
                    st.progress(job.iteration / job.total)
                if job.error:
                    st.error(f"{job.label} failed: {job.error}")
            if job.active:
                button.button("Cancel", key=f"{key}.cancel.{job.id}", on_click=queue.cancel, args=(user, job.id),
                              help="A waiting run is dropped; a training run stops after its current iteration.")
        left, right, _ = st.columns([1, 1, 3])
        if any(j.active for j in jobs):
            left.button("Cancel all", key=f"{key}.cancel_all", on_click=queue.cancel_all, args=(user,))
        if any(not j.active for j in jobs):
            right.button("Clear ended", key=f"{key}.clear", on_click=queue.clear_finished, args=(user,),
                         help="Forget ended jobs here; their runs stay in Your runs.")
    if not show_results:
        return
    entries = [{"group": j.group, "label": j.label, "records": j.records, "total": j.total, "state": j.state,
                "thesis": j.thesis, "env": j.config.env} for j in jobs] + list(extra_runs or [])
    with_records = distinct_labels([(e["label"], e["records"]) for e in entries if e["records"]])
    st.subheader("Results")
    if not with_records:
        st.caption("Curves appear after each run's first iteration.")
    else:
        refs = common_references([e for e in entries if e["records"]])
        left, right = st.columns(2)
        for col, metric, caption in ((left, "performance", "Performance: 0 is a random policy, 1 the expert (Eq 4.2)."),
                                     (right, "aer", "Average episodic reward after each iteration (Eq 4.1); dashed: "
                                                    "the expert's and a random policy's, when every run measured "
                                                    "its Performance against the same ones.")):
            with col:
                fig = figures.compare_runs(with_records, metric, references=refs)
                st.plotly_chart(fig, key=f"{key}.{metric}", config=CHART_CONFIG)
                st.caption(caption)
                chart_downloads(fig, f"compare-{metric}", key=f"{key}.{metric}.dl", note=False,
                                draw=lambda theme="slide", m=metric: figures.compare_runs(with_records, m, theme,
                                                                                         references=refs))
        compare_pack_download(with_records, summary_rows(entries), refs, key=f"{key}.pack")
    st.markdown("**Summary, in the thesis's layout**: one row per configuration; *ours* is the mean ± standard "
                "deviation over its seeds at each seed's latest iteration, beside the number the thesis reports "
                "for the same configuration where it has one.")
    st.dataframe(summary_rows(entries), hide_index=True, width="stretch")
