"""Resilience to sub-optimal experts (thesis Ch. 7): Fig 7.1 from the shipped sweep results, the
expert levels (Table 7.1), and one cell of the study trained live through the background queue.

Thin: the numbers come from `ifo.reproduce.chapter7` (results, the thesis's numbers, configurations),
the figure from `ifo.figures.resilience_curves`, the training from `ifo.ui.queue`.
"""
from functools import partial

import streamlit as st

from ifo import figures
from ifo.reproduce import chapter7 as ch7
from ifo.runtime import limit_threads
from ifo.ui import compare_page as cp
from ifo.ui import storage
from ifo.ui.export import chart_downloads
from ifo.ui.panels import CHART_CONFIG
from ifo.ui.queue import QueueFull, get_queue
from ifo.ui.settings import env_label, fast_overrides, link_by_name

limit_threads()
st.title("Resilience to sub-optimal experts")
st.caption("Thesis Chapter 7: BC, GAIL, ILPO and IUPE learn from five experts of decreasing quality. "
           "Each line is one method's reward against the reward of the expert it watched; the expert itself is "
           "the line y = x. Performance is measured against the expert that demonstrated, so P ≈ 1 means 'as good "
           "as this expert', not 'solved' (Sec 7.3): read it beside P against the best expert and the "
           "trajectory fidelity (how close the agent's states stay to the expert's; 0 = the same states).")

user = storage.current_user()
# The environment, budget, thesis lines and side metric live in the URL, so a link opens the same view;
# `?resilience.env=acrobot` (the configuration's name) works as well as the label the widget writes.
URL = {"bind": "query-params"}
link_by_name("resilience.env", ch7.ENVS_7, env_label)
env = st.selectbox("Environment", list(ch7.ENVS_7), format_func=env_label, key="resilience.env", **URL)
labels = ch7.LABELS_7
methods = st.multiselect("Methods", labels, default=labels, key="resilience.methods")
every_budget = ch7.load_shipped_results(env)
shipped = every_budget

st.subheader("Fig 7.1 from the shipped results")
budgets = ch7.budgets(every_budget)
if len(budgets) > 1:  # e.g. every method with 5 rounds, and GAIL again with 40
    budget = st.radio("Training budget", budgets, format_func=lambda b: ch7.budget_label(every_budget, b),
                      key=f"resilience.budget.{env}", **URL,
                      help="Iterations and demonstration episodes per training ('all': every episode the level "
                           "ships, see the expert levels below). The thesis trained 100; the methods listed with 100 "
                           "iterations ship at that budget too. Adversarial learners (GAIL) need many more rounds "
                           "than the others: a short budget says more about that than about the expert.")
    shipped = ch7.in_budget(every_budget, budget)
results = [r for r in shipped if r["method"] in methods or r["reference"]]
if not budgets:
    st.info(f"No shipped results for {env_label(env)} yet. Make them with `python -m ifo bench resilience "
            f"--envs {env} --seeds 3 --store runs/sweeps/ch7 --ship` (trainings run on Ray).")
elif not any(not r["reference"] for r in results):
    st.info("None of the chosen methods was trained with this budget: choose another budget or method.")
else:
    iters = sorted({r["iterations"] for r in results if r["iterations"]})
    runs = len([r for r in results if not r["reference"]])
    sources = sorted({r["source"] for r in results if not r["reference"]})
    st.caption(f"{runs} trainings from {', '.join(f'`{s}`' for s in sources)}; iterations per run: "
               f"{', '.join(map(str, iters)) or 'per-method defaults'}. Bars: one sd over seeds.")
    gaps = ch7.missing_cells_text(shipped, env, methods)
    if gaps:
        st.info(gaps, icon=":material/info:")
show_thesis = st.toggle("Show the thesis's lines (dotted)", key="resilience.thesis", **URL)
thesis = ch7.thesis_curves(env, methods) if show_thesis else None
left, right = st.columns(2)
with left:  # one drawing for the page and the slides (`draw`), in their two themes
    draw_aer = partial(figures.resilience_curves, results, env, thesis=thesis, colors_by=labels)
    fig = draw_aer()
    st.plotly_chart(fig, key="resilience.aer", config=CHART_CONFIG)
    chart_downloads(fig, f"fig-7-1-{env}", key="resilience.aer.dl", draw=lambda theme="slide": draw_aer(theme=theme))
with right:
    metric = st.radio("Beside it", ["fidelity", "performance", "performance_expert1"], horizontal=True,
                      format_func=figures.RESILIENCE_METRICS.get, key="resilience.metric", **URL)
    draw_other = partial(figures.resilience_curves, results, env, metric=metric, colors_by=labels)
    other = draw_other()
    st.plotly_chart(other, key="resilience.other", config=CHART_CONFIG)
    chart_downloads(other, f"fig-7-1-{env}-{metric}", key="resilience.other.dl", note=False,
                    draw=lambda theme="slide": draw_other(theme=theme))
rows = ch7.summary_rows(results, env, methods + [ch7.expert_label(k) for k in ch7.LEVELS])
if rows:
    st.dataframe(rows, hide_index=True, key="resilience.table")

with st.expander("The expert levels (Table 7.1)"):
    st.dataframe(ch7.level_rows(env), hide_index=True, key="resilience.levels")
    st.caption("Levels 2-5 are earlier checkpoints of one stable-baselines3 training run, each chosen so that its "
               "AER on the 100 evaluation episodes meets the thesis's; their 100 demonstrations are recorded on "
               "other seeds (the thesis used 1,000).")

st.subheader("Run one cell live")
st.caption("One method on one expert's demonstrations, trained in the background queue (saved to *Your runs*).")
c1, c2, c3, c4 = st.columns(4)
method = c1.selectbox("Method", labels, key="resilience.live.method")
level = c2.selectbox("Expert", list(ch7.LEVELS), format_func=ch7.expert_label, key="resilience.live.level")
seed = int(c3.number_input("Seed", min_value=0, max_value=1000, value=0, step=1, key="resilience.live.seed"))
iterations = int(c4.number_input("Iterations", min_value=1, max_value=100, value=ch7.SHIPPED_SETTINGS["iterations"],
                                 step=1, key="resilience.live.iterations",
                                 help=f"Every method's shipped results used {ch7.SHIPPED_SETTINGS['iterations']} "
                                      f"iterations and {ch7.SHIPPED_SETTINGS['expert_episodes']} demonstrations "
                                      "per run; some also ship with a longer budget (above)."))
queue = get_queue()
if st.button("Queue this cell", key="resilience.live.queue", type="primary"):
    method_name = dict(ch7.METHODS_7)[method]
    try:
        config = ch7.live_config(env, method_name, level, seed, iterations, overrides=fast_overrides())
        group = f"Ch. 7 · {method} · {ch7.expert_label(level)} · {env_label(env)}"
        theirs = ch7.thesis_point(level, method, env)
        queue.submit(user, config, label=f"{group}, seed {seed}", group=group,
                     thesis=None if theirs is None else (theirs[2], theirs[0]))
        st.success(f"Queued {method} on {ch7.expert_label(level)}'s demonstrations.")
    except (QueueFull, ValueError, FileNotFoundError) as e:
        st.error(str(e))


@st.fragment(run_every=cp.REFRESH_SECONDS if queue.active(user) else None)
def live() -> None:
    mine = [j for j in queue.jobs(user) if j.group.startswith("Ch. 7 · ")]
    if not mine:
        st.caption("Nothing queued from this page yet.")
        return
    cp.queue_panel(user, queue, "resilience.queue", show_results=False)
    table = []
    for job in mine:
        m = ch7.live_metrics(job.records, job.config.env, int(job.config.expert_level))
        table.append({"cell": job.label, "state": cp.STATE_TEXT.get(job.state, job.state),
                      "iteration": f"{job.iteration}/{job.total}",
                      "AER": "—" if m is None else f"{m['aer']:.1f}",
                      "P (against this expert)": "—" if m is None or m["performance"] is None
                      else f"{m['performance']:.3f}",
                      "P against Expert¹": "—" if m is None or m["performance_expert1"] is None
                      else f"{m['performance_expert1']:.3f}",
                      "trajectory fidelity": "—" if m is None or m["fidelity"] is None else f"{m['fidelity']:.3f}",
                      "thesis (P, AER)": "—" if job.thesis is None else f"{job.thesis[0]:.2f}, {job.thesis[1]:.1f}"})
    st.dataframe(table, hide_index=True, key="resilience.live.table")


live()
