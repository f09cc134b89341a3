"""Compare and ablate: queue several configurations (methods, the thesis's ablation switches,
seeds, or a whole ablation table in one click), let the background queue train them, and
read their curves on shared axes with a summary table beside the thesis's numbers.

Training happens in `ifo.ui.queue` (one bounded queue per server process); this page only
queues jobs and shows their status, refreshed by a fragment while any job is active.
"""
import streamlit as st

from ifo.components.sampling import SAMPLING_MODES
from ifo.learners.bco import SAMPLING_LABELS
from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.methods import METHODS
from ifo.reproduce import TABLES
from ifo.runtime import limit_threads
from ifo.ui import compare_page as cp
from ifo.ui import storage
from ifo.ui.queue import QueueFull, get_queue
from ifo.ui.settings import app_envs, default_iterations, env_label, method_label

limit_threads()
st.title("Compare and ablate")
st.caption("Queue several configurations; they train one after another in the background and appear here "
           "on shared axes, with a table laid out like the thesis's and its numbers beside ours.")

user = storage.current_user()
queue = get_queue()

env = st.selectbox("Environment", app_envs(), format_func=env_label, key="compare.env")
demos, blocked = None, False
if get_env(env).registered:  # a researcher's own environment: it learns from the user's demonstrations
    own = {d.name: d for d in storage.list_demos(user) if d.env == env}
    if own:
        name = st.selectbox("Demonstrations", list(own), format_func=lambda n: f"{n} (from {own[n].original_name})",
                            key=f"compare.demos.{env}", help="Your uploads for this environment (Your runs).")
        demos = storage.demos_settings(own[name])
    else:
        st.info(f"{env_label(env)} learns from your demonstrations: upload them on *Your runs* first.")
        blocked = True
c1, c2 = st.columns(2)
seeds = int(c1.number_input("Seeds per configuration", min_value=1, max_value=5, value=1, step=1,
                            key="compare.seeds", help="Each seed is one run; the table shows mean ± sd over seeds."))
iterations = int(c2.number_input("Iterations per run", min_value=1, max_value=200, step=1,
                                 value=default_iterations(env, "bco-alpha"), key=f"compare.iterations.{env}",
                                 help="Single-pass methods (BCO) always do one."))


def submit(planned: list) -> None:
    try:
        n = cp.queue_jobs(planned, seeds, user, queue)
    except QueueFull as e:
        st.session_state["compare.flash"] = ("error", str(e))
    except ValueError as e:  # an impossible combination of settings
        st.session_state["compare.flash"] = ("error", f"These settings cannot make a run: {e}")
    else:
        st.session_state["compare.flash"] = ("success", f"Queued {n} run{'s' * (n != 1)}.")


by_method, by_switch, presets = st.tabs(["Methods", "Ablation switches", "Thesis ablation tables"])
with by_method:
    methods = st.multiselect("Methods", list(METHODS), default=["bco-alpha", "iupe"], format_func=method_label,
                             key="compare.methods")
    if st.button("Queue these methods", key="compare.queue_methods", type="primary", disabled=blocked or not methods):
        submit(cp.method_configs(env, methods, iterations, demos))
with by_switch:
    st.caption("The one BCO loop with components switched on by hand, as in the thesis's Tables 5.2 and 6.2.")
    a, s, e = st.columns(3)
    attention = a.checkbox("Attention", key="compare.attention", help="Gated self-attention in the IDM and policy.")
    sampling = s.selectbox("Sampling", SAMPLING_MODES, key="compare.sampling", format_func=SAMPLING_LABELS.get,
                           help="How I_s mixes random (I_pre) and the policy's own successful (I_pos) transitions.")
    exploration = e.checkbox("Exploration", key="compare.exploration",
                             help="Sample labels and rollout actions from the softmax instead of the MAP action.")
    if st.button("Queue this configuration", key="compare.queue_switches", type="primary", disabled=blocked):
        submit([cp.switch_config(env, attention, sampling, exploration, iterations, demos)])
with presets:
    here = st.checkbox(f"Run the tables on {env_label(env)} instead of the thesis's maze", key="compare.preset_here",
                       help="The 10×10 maze takes long on a laptop; a smaller maze shows the same ideas sooner. "
                            "The thesis's numbers appear only where it reports one for that environment.")
    for table_id in cp.PRESET_TABLES:
        table = TABLES[table_id]
        target = env if here else table.envs[0]
        st.markdown(f"**{table.title}**: {len(table.rows)} rows × {seeds} seed{'s' * (seeds != 1)} "
                    f"on {env_label(target)}")
        if st.button(f"Queue Table {table_id}", key=f"compare.preset.{table_id}", disabled=blocked and here):
            submit(cp.preset_configs(table_id, target, iterations if here else None, demos if here else None))

flash = st.session_state.pop("compare.flash", None)
if flash:
    (st.error if flash[0] == "error" else st.success)(flash[1])

saved = [r for r in storage.list_runs(user) if not r.damaged]  # a damaged run has no curve to compare
chosen = st.multiselect("Also compare saved runs", [r.run_id for r in saved], key="compare.saved",
                        format_func=lambda rid: next((r.label for r in saved if r.run_id == rid), rid),
                        help="Runs from Your runs (including ones queued before the server restarted).")
extra = []
for r in saved:
    if r.run_id in chosen:
        try:
            thesis = None if r.config.get("demos") else cp.thesis_numbers(RunConfig.from_dict(r.config))
        except ValueError:  # a run saved by an older version
            thesis = None
        extra.append({"group": r.label, "label": r.label, "records": storage.last_records(r),
                      "total": r.iterations_total or r.iterations_done, "state": "done", "thesis": thesis,
                      "env": r.config.get("env")})

st.subheader("Queue")


@st.fragment(run_every=cp.REFRESH_SECONDS if queue.active(user) else None)
def live() -> None:
    cp.queue_panel(user, queue, "compare", extra_runs=extra)
    if not queue.active(user) and st.session_state.get("compare.was_active"):
        st.session_state["compare.was_active"] = False
        st.rerun()  # the last job ended: redraw the page once, which stops the timer
    st.session_state["compare.was_active"] = queue.active(user)


live()
