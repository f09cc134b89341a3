"""Lessons for the landing page: a few runs where something visibly happens, each with a sentence
on what to watch. A lesson's run is a set of the step page's URL settings (the same parameters its
bound widgets use), so a lesson is also a link a teacher can share.

The settings were chosen from measured runs: `python -m ifo bench vanishing` (BCO(α) collapses on
4 of 10 seeds with a 300-transition I_pre, IUPE recovers on 9; seed 5 shows both), and the
shipped example runs (docs/REPRODUCTION.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import streamlit as st

from ifo.ui.settings import env_label, iterations_key, method_label

STEP_KEY = "step"


@dataclass(frozen=True)
class LessonRun:
    label: str  # the button: "Open BCO(α)"
    env: str
    method: str
    settings: dict  # more URL settings (flat field names), e.g. {"pre_size": 300, "seed": 5}
    iterations: int | None = None

    def query(self) -> dict:
        q = {f"{STEP_KEY}.env": env_label(self.env), f"{STEP_KEY}.method": method_label(self.method)}
        if self.iterations is not None:
            q[iterations_key(STEP_KEY, self.env, self.method)] = str(self.iterations)
        q.update({f"{STEP_KEY}.{k}": str(v).lower() if isinstance(v, bool) else str(v) for k, v in self.settings.items()})
        return q


@dataclass(frozen=True)
class Lesson:
    title: str
    watch: str  # what to look at, in one or two sentences
    runs: tuple[LessonRun, ...]


LESSONS = (
    Lesson("Vanishing actions: why IUPE samples", "With only 300 random transitions the first IDM is weak. Step "
           "BCO(α) and watch *IDM predictions through time*: one action swallows the others and the reward stays "
           "near 10. Then step IUPE from the same seed: the IDM keeps every action and the reward climbs to 500.",
           (LessonRun("Open BCO(α)", "cartpole", "bco-alpha", {"seed": 5, "pre_size": 300}, 5),
            LessonRun("Open IUPE", "cartpole", "iupe", {"seed": 5, "pre_size": 300}, 5))),
    Lesson("Iterating helps: BCO against BCO(α) on MountainCar", "BCO makes one pass: label the expert with an IDM "
           "trained on random pushes, clone, stop. BCO(α) goes on learning from its own runs: watch Performance "
           "rise from about one half to the expert's as the car learns to swing.",
           (LessonRun("Open BCO", "mountaincar", "bco", {}), LessonRun("Open BCO(α)", "mountaincar", "bco-alpha", {}))),
    Lesson("A maze from scratch, and where the policy looks", "IUPE on 5×5 mazes as the thesis ran them. Step and "
           "watch *Where the policy looks* (Grad-CAM): at first the heat is anywhere; as Performance rises it "
           "settles on the agent and the walls around it. An iteration takes a few seconds.",
           (LessonRun("Open IUPE on Maze 5×5", "maze5", "iupe",
                      {"maze_eval_layouts": "the demonstrations' layouts (thesis)", "deadlock_guard": True}),)),
    Lesson("Learning from its own rewards: CRIL", "One expert trajectory only. CRIL imitates like IUPE and also "
           "updates its policy from its own rewards (TD). Watch ε, its exploration, fall as the policy grows sure, "
           "and the replay memory fill.",
           (LessonRun("Open CRIL", "cartpole", "cril", {"expert_episodes": 1}),)),
)


def open_lesson(run: LessonRun, step_page) -> None:
    """Go to the step page with this lesson run's settings, in a fresh run (the current one is saved)."""
    for key in [k for k in st.session_state if str(k).startswith(f"{STEP_KEY}.") or k == f"ifo.slot.{STEP_KEY}"]:
        del st.session_state[key]
    st.switch_page(step_page, query_params=run.query())


def lessons(step_page) -> None:
    """The landing page's lessons: title, what to watch, one button per run."""
    st.subheader("Lessons")
    st.caption("Each opens the step page with settings where something visibly happens; press Step and watch.")
    for k, lesson in enumerate(LESSONS):
        with st.container(border=True):
            st.markdown(f"**{lesson.title}**")
            st.markdown(lesson.watch)
            for col, run in zip(st.columns(max(2, len(lesson.runs))), lesson.runs):
                if col.button(run.label, key=f"lesson.{k}.{run.method}.{run.env}"):
                    open_lesson(run, step_page)
