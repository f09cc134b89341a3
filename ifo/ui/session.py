"""The session's current run: kept in `st.session_state`, stepped one iteration at a time.

A page owns a `RunSlot` (named, so several pages can each keep their own run). The slot

- builds a `Run` from the settings, and a new one whenever the environment, method or seed
  change (changing only the number of iterations keeps the run and its records);
- remembers a *target* iteration: Step asks for one more, Run N for N more ("playing");
- advances at most one iteration per script run (`advance`), so a fragment that reruns
  every `tick` seconds while playing trains one iteration per rerun and the page stays
  usable between iterations;
- shows the Run's `progress(phase, iteration)` callback as a progress bar.

Clicks that arrive while an iteration trains are held back until the iteration ends (a
Streamlit rerun request raised inside `Run.step()` would leave the run half-trained). A
click during a fragment run makes Streamlit start the full rerun at once, in another
thread, while the cancelled fragment finishes its iteration: a per-slot lock makes the
new run wait for it, so one run never trains twice at once and the page shows the true
count. At most IFO_LAB_MAX_TRAININGS (default 2) iterations train at once across all
sessions, because every session shares one process and a couple of cores.
"""
from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass, field, replace

import streamlit as st
from streamlit.runtime.scriptrunner_utils.exceptions import ScriptControlException

from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.run import PHASES, Run, RunFinished
from ifo.ui.settings import Choice, method_label

log = logging.getLogger(__name__)

TICK_SECONDS = 0.3  # fragment rerun interval while playing
_TRAININGS = threading.BoundedSemaphore(max(1, int(os.environ.get("IFO_LAB_MAX_TRAININGS", "2"))))

PHASE_TEXT = {
    "idm": "training the inverse dynamics model (IDM) on I_s",
    "label": "labelling the expert's state pairs with the IDM",
    "policy": "training the policy on those labels",
    "attention": "computing attention maps on probe images",
    "rollout": "running the policy to collect its own experience (I_pos)",
    "sampling": "choosing what the IDM learns from next (I_s)",
    "evaluate": "measuring the policy: AER and Performance",
}


def _identity(config: RunConfig) -> dict:
    """What makes a run a different run: everything but the number of iterations."""
    return {**config.to_dict(), "iterations": None}


def describe(config: RunConfig) -> str:
    spec = get_env(config.env)
    return f"{method_label(config.method)} on {spec.thesis_name or spec.name}, seed {config.seed}"


@dataclass
class SlotState:
    run: Run | None = None
    identity: dict | None = None
    error: str | None = None  # why no run could be built from the current settings
    step_error: str | None = None  # why the last iteration failed
    target: int = 0  # iteration the user asked to reach
    playing: bool = False  # Run N in progress
    reset_requested: bool = False
    training: bool = False  # an iteration is training right now (maybe in another thread)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)  # one iteration at a time
    notices: list[str] = field(default_factory=list)


class _ProgressBar:
    """The Run's progress callback, drawn into one placeholder. Streamlit raises its rerun/stop
    requests at st.* calls; inside Run.step() we hold them back and re-raise after the step."""

    def __init__(self, area, run: Run):
        self.area, self.total = area, run.config.iterations
        self.deferred: BaseException | None = None

    def show(self, fn, *args, **kwargs) -> None:
        if self.deferred is not None:
            return
        try:
            fn(*args, **kwargs)
        except ScriptControlException as e:
            self.deferred = e

    def __call__(self, phase: str, iteration: int) -> None:
        # ifo.run.PHASES lists every phase in order; a method skips some, so the bar may jump
        done = PHASES.index(phase) / len(PHASES) if phase in PHASES else 0.0
        text = f"Iteration {iteration} of {self.total}: {PHASE_TEXT.get(phase, phase)}"
        self.show(self.area.progress, done, text=text)


class RunSlot:
    """One run kept in session state under `name`."""

    def __init__(self, name: str = "step"):
        self.key = f"ifo.slot.{name}"
        if self.key not in st.session_state:
            st.session_state[self.key] = SlotState()

    @property
    def state(self) -> SlotState:
        return st.session_state[self.key]

    @property
    def run(self) -> Run | None:
        return self.state.run

    @property
    def records(self) -> list[dict]:
        return self.run.records if self.run is not None else []

    @property
    def playing(self) -> bool:
        return self.state.playing

    @property
    def tick(self) -> float | None:
        """`run_every` for the page's live fragment: rerun it while playing, never otherwise."""
        return TICK_SECONDS if self.state.playing else None

    # ------------------------------------------------------------------ building
    def ensure(self, choice: Choice) -> Run | None:
        """The run for these settings: the current one, or a new one if env/method/seed changed
        or Reset was pressed. None (with `error` set) when the settings cannot make a run."""
        s = self.state
        try:
            config = choice.config()
        except ValueError as e:
            s.error, s.playing = f"These settings cannot make a run: {e}", False
            return None
        identity = _identity(config)
        if identity == s.identity and not s.reset_requested:
            if s.run is not None:
                s.error = None  # an earlier impossible setting was put right
            if s.run is not None and s.run.config.iterations != config.iterations:
                s.run.config = replace(s.run.config, iterations=config.iterations)  # keep the records
                s.target = min(s.target, config.iterations)
            return s.run
        previous = s.run
        s.reset_requested = s.playing = False
        s.run, s.identity, s.error, s.step_error, s.target = None, identity, None, None, 0
        with st.spinner(f"Preparing a new run ({describe(config)}): loading the demonstrations "
                        "and collecting random transitions..."):
            try:
                s.run = Run(config)
            except Exception as e:  # a missing demonstrations file, an impossible combination, ...
                if isinstance(e, ValueError):  # DemoError and bad settings: the message says it all
                    log.warning("could not build a run: %s", e)
                else:
                    log.exception("could not build a run")
                s.error = f"Could not start a run of {describe(config)}: {e}"
                return None
        if previous is not None and previous.records:
            s.notices.append(f"New run: {describe(config)}. The previous run "
                             f"({describe(previous.config)}, {previous.iteration} iterations) was discarded.")
        return s.run

    def describe(self) -> str:
        """A one-line name of the current run, e.g. "BCO(α) on CartPole, seed 0"."""
        return describe(self.run.config) if self.run is not None else ""

    @property
    def error(self) -> str | None:
        return self.state.error

    def pop_notices(self) -> list[str]:
        notes, self.state.notices = self.state.notices, []
        return notes

    # ------------------------------------------------------------------ button callbacks
    # They run at the start of a script run, possibly while an iteration the user interrupted
    # still trains in another thread: count that iteration as done.
    def _base(self) -> int:
        s = self.state
        return s.run.iteration + (1 if s.training else 0)

    def request_reset(self) -> None:
        self.state.reset_requested = True

    def request_step(self) -> None:
        s = self.state
        if s.run is not None:
            s.playing, s.step_error = False, None
            s.target = min(self._base() + 1, s.run.config.iterations)

    def request_run(self, n: int) -> None:
        s = self.state
        if s.run is not None:
            s.step_error = None
            s.target = min(self._base() + int(n), s.run.config.iterations)
            s.playing = s.target > s.run.iteration

    def pause(self) -> None:
        s = self.state
        s.playing = False
        if s.run is not None:
            s.target = self._base()

    # ------------------------------------------------------------------ training
    def advance(self, area) -> bool:
        """Train one iteration if the run is behind its target, showing progress in `area`
        (an st.empty()). Returns True when this iteration ended a Run N, so the page can rerun
        in full and stop the fragment's timer."""
        s = self.state
        if s.run is None:
            return False
        bar = _ProgressBar(area, s.run)
        # Streamlit starts a full rerun without waiting for a fragment run it cancels, so two
        # threads of this session can get here at once: one trains, the other waits for it.
        _acquire(s.lock, bar, area, "Finishing the iteration in progress...")
        try:
            return self._advance_locked(bar, area)
        finally:
            s.lock.release()

    def _advance_locked(self, bar: "_ProgressBar", area) -> bool:
        s, run = self.state, self.state.run
        if run.iteration >= min(s.target, run.config.iterations):
            if s.playing:
                s.playing = False
                return True
            return False
        _acquire(_TRAININGS, bar, area, "Waiting for other sessions' training to finish...")
        s.training = True
        try:
            run.progress = bar
            run.step()
        except RunFinished:
            s.playing = False
        except Exception as e:
            log.exception("iteration failed")
            s.step_error = f"Iteration {run.iteration + 1} failed: {e}"
            s.playing, s.target = False, run.iteration
        finally:
            s.training = False
            run.progress = None
            _TRAININGS.release()
            bar.show(area.empty)
        if bar.deferred is not None:  # the click that arrived during the iteration: handle it now
            raise bar.deferred
        if s.playing and run.iteration >= min(s.target, run.config.iterations):
            s.playing = False
            return True
        return False


def _acquire(lock, bar: _ProgressBar, area, message: str) -> None:
    """Take `lock`, showing `message` while waiting; a click while waiting abandons the wait."""
    if lock.acquire(blocking=False):
        return
    while bar.deferred is None and not lock.acquire(timeout=0.25):
        bar.show(area.info, message)
    if bar.deferred is not None:
        raise bar.deferred
