"""Step through a run: pick an environment, a method and its switches, then Step, Play or Reset.

Thin by design: widgets (ifo.ui.settings) -> RunConfig -> the session's Run (ifo.ui.session)
-> records -> the registry's panels (ifo.ui.registry, drawn by ifo.ui.panels) and the loop
diagram (ifo.ui.diagram). Training happens in this process, one iteration per script run;
while playing, a fragment reruns every `slot.tick` seconds and trains one iteration each
time, so every button keeps working. Each iteration is autosaved under the URL's user.
URL: the settings live in it (share the link); `?hide=settings,diagram,...` hides parts
for a lesson; `?run=<id>` reopens a saved run.
IFO_LAB_FAST=1 shrinks every run (see ifo.ui.settings).
"""
import streamlit as st

from ifo.runtime import limit_threads
from ifo.ui.diagram import loop_diagram
from ifo.ui.panels import CHART_CONFIG, PanelContext, for_screen, show_records
from ifo.ui import storage
from ifo.ui.session import RunSlot, hidden, lesson_link, lesson_parts
from ifo.ui.settings import choice_without_widgets, run_settings

limit_threads()
KEY = "step"
hide = hidden()
st.title("Step through a run")
st.caption("Each press of Step is one iteration of the BCO loop: train the IDM, label the expert's "
           "state pairs, train the policy, run it, and choose what the IDM learns from next.")

slot = RunSlot(KEY)
slot.state.user = storage.current_user()
slot.open_from_url(KEY)  # ?run=<id>: a saved run, before the widgets take their values
choice = choice_without_widgets(KEY) if "settings" in hide else run_settings(KEY, bind=True)
run = slot.ensure(choice)
for note in slot.pop_notices():
    st.toast(note)
pending = slot.state.pending_branch
if pending is not None:  # a switch changed in the middle of a run: branch from here, or start again?
    changed = ", ".join(f"**{k}** → {v}" for k, v in pending["changes"].items())
    with st.container(border=True):
        st.markdown(f"You changed {changed} after {run.iteration if run else 0} iterations. Continue from here "
                    "as a branch (the same I_pre and models so far, the new setting from the next Step on), or "
                    "start a new run from scratch? The run so far is kept either way.")
        left, right, _ = st.columns([1, 1, 2])
        left.button(f"Branch from iteration {run.iteration if run else 0}", key="branch", type="primary",
                    on_click=slot.answer_branch, args=("branch",))
        right.button("Start a new run", key="branch_new", on_click=slot.answer_branch, args=("new",))
if run is None:
    st.error(slot.error)
    st.button("Try again", on_click=slot.request_reset, key="retry")
    st.stop()

sizes = run.learner.sizes()
boxes = {p.name: p.box for p in run.learner.phases}
timer = slot.tick  # the fragment's run_every, fixed for this page run


def controls():
    st.markdown(f"**Current run:** {slot.describe()}")
    done = run.finished or slot.state.pending_branch is not None  # answer the branch question first
    step, n_col, play, to_end, reset = st.columns([1, 1, 1, 1.3, 1], vertical_alignment="bottom")
    step.button("Step", key="step", type="primary", on_click=slot.request_step, disabled=done,
                help="Train one iteration.", width="stretch")
    n_col.number_input("N", min_value=1, max_value=1000, value=5, step=1, key="run_n",
                       help="How many iterations Run N trains, one after another.")
    if slot.playing:
        play.button("Pause", key="pause", on_click=slot.pause, width="stretch",
                    help="Stop after the iteration that is training now.")
    else:
        play.button("Run N", key="run", on_click=lambda: slot.request_run(st.session_state["run_n"]),
                    disabled=done, width="stretch", help="Play: train the next N iterations, one after another.")
    to_end.button("Run to the end", key="run_all", on_click=slot.request_run_to_end,
                  disabled=done or slot.playing, width="stretch",
                  help=f"Play every remaining iteration (up to {run.config.iterations}); Pause stops it.")
    reset.button("Reset", key="reset", on_click=slot.request_reset, width="stretch",
                 help="Start this run again from scratch with the current settings.")
    with st.popover("Share read-only", icon=":material/share:"):
        link = slot.share_link()
        if link is None:
            st.caption("Step once first: a run can be shared once it is saved.")
        else:
            st.code(link, language=None)
            st.caption("Students who open this link watch this run (they cannot change it) and see your Steps "
                       "as they happen; each can make their own copy to play with.")
    if done:
        st.success(f"The run has done all {run.config.iterations} iterations. Press Reset to start again, "
                   "or raise the number of iterations in the sidebar to continue.")


def page_must_follow() -> bool:
    """What the fragment cannot do on its own: a Reset (a new run, built above), or a Play started or
    stopped (the fragment's timer is set when the page runs)."""
    return slot.state.reset_requested or slot.tick != timer


# The buttons live in the fragment, so a Step reruns the fragment only: the title, the settings and
# the sidebar are not drawn again for each Step (what thirty students pressing Step at once queue on).
@st.fragment(run_every=timer)
def live():
    if page_must_follow():
        st.rerun()
    controls_area = st.container()
    progress, count_area, scrub_area, diagram_area = st.empty(), st.empty(), st.empty(), st.empty()
    last = {"phase": None, "draws": 0}

    def on_phase(phase, iteration):  # highlight the phase being trained
        if "diagram" in hide or phase == last["phase"]:
            return
        last["phase"], last["draws"] = phase, last["draws"] + 1
        # a key per draw: a phase may come back within one iteration (the maze's attention probes),
        # and two unkeyed charts with the same figure would share one auto-generated id
        diagram = loop_diagram(run.records[-1] if run.records else None, phase, **sizes, phase_boxes=boxes,
                               doing=run.phase_text(phase), layout=run.learner.diagram)
        diagram_area.plotly_chart(for_screen(diagram), key=f"step.diagram.live.{last['draws']}", config=CHART_CONFIG)

    slot.advance(progress, on_phase)
    if page_must_follow():  # a Play just ended (or failed): stop the timer
        st.rerun()
    if "controls" not in hide:
        with controls_area:  # drawn after the iteration, so Step's state is the run's new one
            controls()
            if run.last_step_cached and run.records:
                st.caption(f"Iteration {run.iteration} was ready when Step was pressed: computed ahead while the last "
                           "one was on screen, or by another session on the same lesson. The same numbers as "
                           "training it now.")
    slot.sync_url()
    if slot.state.step_error:
        st.error(slot.state.step_error)
    if slot.state.save_error:
        st.warning(slot.state.save_error)
        if slot.state.save_conflict:
            left, right, _ = st.columns([1, 1, 2])
            left.button("Reopen the latest save", key="save.reopen", on_click=slot.reopen_latest, args=(KEY,))
            right.button("Keep mine as a copy", key="save.copy", on_click=slot.keep_as_copy)
    records = slot.records
    show_records(records, run.config.iterations, hide, sizes, (count_area, scrub_area, diagram_area),
                 lambda shown: PanelContext(slot, run, records, shown), layout=run.learner.diagram)
    if not records:
        st.info("Press **Step** to train the first iteration.")
        return
    if run.method.sees_expert_actions:
        st.info(f"{run.method.title} learns from the expert's true actions: it is the reference that is allowed "
                "to see them, so there is no IDM to show.")
    slot.compute_ahead()  # the next iteration, while the class looks at this one


live()

if "controls" not in hide:
    with st.expander("Build a lesson link", icon=":material/link:"):
        st.caption("Choose what the class sees: the link opens this page with the current settings and hides the "
                   "parts you pick (it carries no user id: each student gets their own runs).")
        lesson_hide = st.multiselect("Hide", lesson_parts(), format_func=lesson_parts().get, key="lesson.hide",
                                     placeholder="Nothing hidden")
        st.code(lesson_link(lesson_hide), language=None)
