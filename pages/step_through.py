"""Step through a run: pick an environment and a method, then Step, Run N or Reset.

Thin by design: widgets (ifo.ui.settings) -> RunConfig -> the session's Run (ifo.ui.session)
-> records -> figures from ifo.figures -> screen (ifo.ui.panels). Training happens in this
process, one iteration per script run; while *Run N* plays, a fragment reruns every
`slot.tick` seconds and trains one iteration each time, so every button keeps working.
IFO_LAB_FAST=1 shrinks every run (see ifo.ui.settings).
"""
import streamlit as st

from ifo import figures
from ifo.runtime import limit_threads
from ifo.ui.panels import counter, grid, metrics_row
from ifo.ui.session import RunSlot
from ifo.ui.settings import run_settings

limit_threads()
st.title("Step through a run")
st.caption("Each press of Step is one iteration of the BCO loop: train the IDM, label the expert's "
           "state pairs, train the policy, run it, and choose what the IDM learns from next.")

slot = RunSlot("step")
choice = run_settings("step")
run = slot.ensure(choice)
for note in slot.pop_notices():
    st.toast(note)
if run is None:
    st.error(slot.error)
    st.button("Try again", on_click=slot.request_reset, key="retry")
    st.stop()

controls = st.container()


@st.fragment(run_every=slot.tick)
def live():
    if slot.advance(st.empty()):  # a Run N just ended: redraw the buttons, stop the timer
        st.rerun()
    if slot.state.step_error:
        st.error(slot.state.step_error)
    records, names = slot.records, run.spec.action_names
    counter(run.iteration, run.config.iterations)
    if not records:
        st.info("Press **Step** to train the first iteration.")
        return
    metrics_row(records)
    has_idm = "idm" in records[-1]
    panels = [
        (figures.learning_curve(records, "aer"), "step.aer",
         "Average episodic reward: the learner's mean score after each iteration, "
         "with the expert's and a random policy's scores as dashed lines."),
        (figures.learning_curve(records, "performance"), "step.performance",
         "Performance rescales that score so a random policy is 0 and the expert is 1."),
    ]
    if has_idm:
        panels.append((figures.idm_predictions(records, names), "step.idm",
                       "What the IDM says the expert did on each demonstrated transition, next to what it really "
                       "did: the true actions are hidden from the learner and shown only to you."))
    panels.append((figures.accuracy_curves(records), "step.accuracy",
                   "How often the IDM's labels and the policy's choices match the expert's hidden actions."))
    if any("rollouts" in r for r in records):
        panels.append((figures.win_probability(records), "step.win",
                       "The share of the policy's own runs in each iteration that reached the goal."))
    if has_idm:
        panels.append((figures.idm_predictions_over_time(records, names), "step.idm_over_time",
                       "The IDM's predicted share of each action, iteration after iteration; "
                       "dotted lines are the true shares."))
    grid(panels)
    if not has_idm:
        st.info("BC learns from the expert's true actions, so there is no IDM to show.")


live()

with controls:
    st.markdown(f"**Current run:** {slot.describe()}")
    done = run.finished
    step, n_col, run_n, reset = st.columns([1, 1, 1, 1], vertical_alignment="bottom")
    step.button("Step", key="step", type="primary", on_click=slot.request_step, disabled=done,
                help="Train one iteration.", width="stretch")
    n_col.number_input("N", min_value=1, max_value=1000, value=5, step=1, key="run_n",
                       help="How many iterations Run N trains, one after another.")
    if slot.playing:
        run_n.button("Pause", key="pause", on_click=slot.pause, width="stretch",
                     help="Stop after the iteration that is training now.")
    else:
        run_n.button("Run N", key="run", on_click=lambda: slot.request_run(st.session_state["run_n"]),
                     disabled=done, width="stretch",
                     help="Train the next N iterations (stops at the end of the run).")
    reset.button("Reset", key="reset", on_click=slot.request_reset, width="stretch",
                 help="Start this run again from scratch with the current settings.")
    if done:
        st.success(f"The run has done all {run.config.iterations} iterations. Press Reset to start again, "
                   "or raise the number of iterations in the sidebar to continue.")
