"""Your runs: the runs saved in this browser user's folder (the `?user=` id in the URL), the
finished example runs shipped with the app, and your own demonstrations.

Open sends a run to the step page (`?run=<id>&user=<id>`), where it can be scrubbed and
trained further; rename, delete (with a confirmation) and download (a ZIP of its folder)
act on the saved folder through `ifo.ui.storage`. A damaged run is listed with what is wrong
and can only be deleted. Uploaded demonstrations are validated
before they replace anything; "Train" queues a run on them in the background queue.
"""
import streamlit as st

from ifo.config import RunConfig
from ifo.data.demos import DemoError
from ifo.methods import METHODS
from ifo.runtime import limit_threads
from ifo.ui import compare_page as cp
from ifo.ui import storage
from ifo.ui.queue import QueueFull, get_queue
from ifo.ui.settings import app_envs, env_label, fast_overrides, method_label

STEP_PAGE = "views/step_through.py"
limit_threads()
st.title("Your runs")
user = storage.current_user()
st.caption(f"Runs are kept for the link in your address bar (user `{user}`): bookmark it to find them again, "
           "from this or another computer.")


def flash(kind: str, text: str) -> None:
    st.session_state["runs.flash"] = (kind, text)


def do_rename(run_id: str) -> None:
    try:
        storage.rename_run(user, run_id, st.session_state.get(f"runs.name.{run_id}", ""))
    except (ValueError, FileNotFoundError) as e:
        flash("error", f"Could not rename the run: {getattr(e, 'reason', e)}")  # reason: no server path
    else:
        flash("success", "Renamed.")


def do_delete(run_id: str, label: str) -> None:
    try:
        storage.delete_run(user, run_id)
    except (ValueError, FileNotFoundError) as e:
        flash("error", f"Could not delete the run: {getattr(e, 'reason', e)}")
    else:
        flash("success", f"Deleted {label}.")


def open_run(run_id: str) -> None:
    """Navigate to the step page with the run in the URL (outside callbacks: switch_page reruns)."""
    try:
        storage.get_run(user, run_id)
    except (ValueError, FileNotFoundError) as e:
        st.error(f"Could not open the run: {e}")
        return
    st.switch_page(STEP_PAGE, query_params={"run": run_id, storage.USER_PARAM: user})


def summary(config: dict, done: int, last: dict | None) -> str:
    try:
        what = f"{method_label(config['method'])} on {env_label(config['env'])}, seed {config.get('seed', 0)}"
    except (KeyError, ValueError):
        what = "unknown configuration"
    text = f"{what} · {done} of {config.get('iterations') or '?'} iterations"
    if config.get("demos"):
        text += " · your demonstrations"
    if last:
        text += f" · AER {last['aer']:.2f}" if last.get("aer") is not None else ""
        text += f" · P {last['performance']:.2f}" if last.get("performance") is not None else ""
    return text


message = st.session_state.pop("runs.flash", None)
if message:
    (st.error if message[0] == "error" else st.success)(message[1])

# ----------------------------------------------------------------------------- your runs
runs = storage.list_runs(user)
queue = get_queue()
training_now = {j.run_id for j in queue.jobs(user) if j.active}  # the queue still writes to these
if not runs:
    st.info("No saved runs yet. Open an example run below, train one on *Step through a run*, "
            "or queue several on *Compare and ablate*.")
for saved in runs:
    rid = saved.run_id
    with st.container(border=True):
        info, actions = st.columns([2, 3], vertical_alignment="center")
        info.markdown(f"**{saved.label}**")
        b_open, b_zip, b_rename, b_delete = actions.columns(4)
        busy = rid in training_now
        if saved.damaged:  # it cannot be opened, renamed or downloaded; it can be deleted
            info.caption(f":material/warning: This run is damaged and cannot be opened: {saved.damaged}")
            with b_delete.popover("Delete", icon=":material/delete:"):
                st.markdown(f"Delete **{saved.label}** for good?")
                st.button("Yes, delete it", key=f"runs.delete.{rid}", type="primary", on_click=do_delete,
                          args=(rid, saved.label), disabled=busy)
            continue
        info.caption(summary(saved.config, saved.iterations_done, saved.last))
        if busy:
            info.caption(":material/hourglass_top: training in the background: open or delete it once it ends "
                         "(or cancel it below).")
        if b_open.button("Open", key=f"runs.open.{rid}", type="primary", icon=":material/open_in_new:", disabled=busy,
                         help="Scrub through it and train it further on the step page."):
            open_run(rid)
        b_zip.download_button("ZIP", data=lambda rid=rid: storage.zip_run(user, rid), file_name=f"{rid}.zip",
                              mime="application/zip", key=f"runs.zip.{rid}", icon=":material/download:",
                              on_click="ignore", help="Download the run's folder: configuration, records, weights.")
        with b_rename.popover("Rename", icon=":material/edit:"):
            st.text_input("New name", value=saved.label, key=f"runs.name.{rid}", max_chars=120)
            st.button("Save name", key=f"runs.rename.{rid}", on_click=do_rename, args=(rid,))
        with b_delete.popover("Delete", icon=":material/delete:"):
            st.markdown(f"Delete **{saved.label}** for good?")
            st.button("Yes, delete it", key=f"runs.delete.{rid}", type="primary", on_click=do_delete,
                      args=(rid, saved.label), disabled=busy)

# ----------------------------------------------------------------------------- background jobs
if queue.jobs(user):
    @st.fragment(run_every=cp.REFRESH_SECONDS if queue.active(user) else None)
    def training() -> None:
        st.subheader("Training in the background")
        cp.queue_panel(user, queue, "runs.queue", show_results=False)
        if not queue.active(user) and st.session_state.get("runs.was_active"):
            st.session_state["runs.was_active"] = False
            st.rerun()  # a job ended: show its run in the list above
        st.session_state["runs.was_active"] = queue.active(user)

    training()
    st.page_link("views/compare.py", label="Curves and the summary table: Compare and ablate",
                 icon=":material/compare_arrows:", query_params={storage.USER_PARAM: user})

# ----------------------------------------------------------------------------- example runs
st.header("Example runs")
st.caption("Finished runs of the thesis's main configurations, shipped with the app. Opening one copies it into "
           "your runs, so you can scrub through its iterations and keep training it.")
for ex in storage.list_shipped_runs():
    with st.container(border=True):
        info, action = st.columns([4, 1], vertical_alignment="center")
        info.markdown(f"**{ex.label}**")
        info.caption(summary(ex.config, ex.iterations_done, ex.last))
        if action.button("Open a copy", key=f"runs.example.{ex.run_id}", icon=":material/content_copy:"):
            try:
                new_id = storage.copy_shipped_run(user, ex.run_id)
            except (OSError, ValueError) as e:
                st.error(f"Could not copy the example run: {e}")
            else:
                open_run(new_id)

# ----------------------------------------------------------------------------- demonstrations
st.header("Your demonstrations")
st.caption("Upload an expert's demonstrations as an .npz file with `obs`, `rewards` and `episode_starts` "
           "(optionally `actions`, which only BC uses, and `next_obs`): the layout stable-baselines3 and "
           "`imitation` users already have. Files are read as plain numeric arrays, never unpickled.")
with st.form("runs.upload", clear_on_submit=False, border=True):
    up_env = st.selectbox("Environment the demonstrations come from", app_envs(), format_func=env_label,
                          key="runs.upload_env")
    uploaded = st.file_uploader("Demonstrations (.npz)", type=["npz"], key="runs.upload_file",
                                max_upload_size=storage.MAX_UPLOAD_MB)
    if st.form_submit_button("Check and save", type="primary"):
        if uploaded is None:
            st.error("Choose an .npz file first.")
        else:
            try:
                kept = storage.save_demos(user, up_env, uploaded.name, uploaded.getvalue())
            except DemoError as e:
                st.error(f"{e}")
                st.caption("Nothing was saved; files you saved before are unchanged.")
            else:
                s = kept.summary
                st.success(f"Saved {kept.name}: {s.get('episodes')} episodes, {s.get('transitions')} transitions, "
                           f"mean return {s.get('mean_return', 0):.2f}"
                           + ("" if s.get("has_actions") else " (no actions: IfO methods only, not BC)") + ".")

demos = storage.list_demos(user)
for d in demos:
    s = d.summary
    with st.container(border=True):
        info, method_col, go, rm = st.columns([3, 2, 1, 1], vertical_alignment="bottom")
        info.markdown(f"**{d.name}** · {env_label(d.env)}")
        info.caption(f"from {d.original_name} · {s.get('episodes')} episodes · {s.get('transitions')} transitions · "
                     f"mean return {s.get('mean_return') or 0:.2f}" + ("" if s.get("has_actions") else " · no actions"))
        method = method_col.selectbox("Method", list(METHODS), format_func=method_label, key=f"runs.demo_method.{d.name}",
                                      index=list(METHODS).index("iupe"))
        if go.button("Train", key=f"runs.train.{d.name}", type="primary",
                     help="Queue a run on these demonstrations; it trains in the background and appears above."):
            if METHODS[method].sees_expert_actions and not s.get("has_actions"):
                st.error("BC learns from the expert's actions, and this file has none: choose an IfO method.")
            else:
                try:
                    config = RunConfig.from_dict(dict(env=d.env, method=method, **storage.demos_settings(d),
                                                      **fast_overrides(method))).resolved()
                    label = f"{method_label(method)} on {env_label(d.env)} · {d.name}"
                    queue.submit(user, config, label=label, group=label)
                except (QueueFull, ValueError) as e:
                    st.error(f"Could not queue the run: {e}")
                else:
                    flash("success", f"Queued {label}: it trains in the background and appears in your runs.")
                    st.rerun()
        if rm.button("Remove", key=f"runs.demo_delete.{d.name}"):
            try:
                storage.delete_demos(user, d.name)
            except (ValueError, FileNotFoundError) as e:
                st.error(f"Could not remove it: {e}")
            else:
                st.rerun()
