"""The session's current run: kept in `st.session_state`, stepped one iteration at a time.

A page owns a `RunSlot` (named, so several pages can each keep their own run). The slot

- builds a `Run` from the settings, and a new one whenever the environment, method or seed
  change (changing only the number of iterations keeps the run and its records);
- remembers a *target* iteration: Step asks for one more, Run N for N more ("playing");
- advances at most one iteration per script run (`advance`), so a fragment that reruns
  every `tick` seconds while playing trains one iteration per rerun and the page stays
  usable between iterations;
- shows the Run's `progress(phase, iteration)` callback as a progress bar over the run's
  own `phases()` (so skipped phases do not make it jump), and tells the page which phase
  is training (`on_phase`), so the loop diagram can highlight it;
- autosaves the run after each iteration (`ifo.ui.storage.save_run`) under the page's
  user (`?user=` in the URL) and a run id fixed for the run's life, and reopens a saved
  run named by `?run=<run id>` (`open_from_url`);
- caches rollout videos of the policy per iteration (`render_videos`), never in
  st.cache_resource: a model belongs to one session;
- once the page is drawn after a Step, asks the server's one `ComputeAhead` (ifo.ahead,
  `server_ahead`) to train the next iteration in the background (`compute_ahead`), and tells
  it when a Step trains (`stepping`), so it gives way.

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
from contextlib import nullcontext
from dataclasses import dataclass, field, replace

import streamlit as st
from streamlit.runtime.scriptrunner_utils.exceptions import ScriptControlException

from ifo import checkpoint
from ifo.config import RunConfig, configuration_label
from ifo.envs import get_env
from ifo.run import Run, RunFinished
from ifo.ui import storage
from ifo.ui.settings import Choice, set_widgets

log = logging.getLogger(__name__)

TICK_SECONDS = 0.3  # fragment rerun interval while playing
_TRAININGS = threading.BoundedSemaphore(max(1, int(os.environ.get("IFO_LAB_MAX_TRAININGS", "2"))))
_AHEAD_LOCK = threading.Lock()
_AHEAD: dict = {}


def server_ahead():
    """The server's one `ComputeAhead` (ifo.ahead): after a Step, the next iteration trains in the
    background into the shared cache, within the training gate, giving way to any Step. None without
    the cache (IFO_LAB_CACHE_MB=0) or with IFO_LAB_AHEAD=0."""
    cache = storage.iteration_cache()
    if cache is None or os.environ.get("IFO_LAB_AHEAD", "1").strip() == "0":
        return None
    with _AHEAD_LOCK:
        if cache.root not in _AHEAD:
            from ifo.ahead import ComputeAhead

            _AHEAD[cache.root] = ComputeAhead(cache, gate=_TRAININGS)
        return _AHEAD[cache.root]


def _identity(config: RunConfig) -> dict:
    """What makes a run a different run: everything but the number of iterations."""
    return {**config.to_dict(), "iterations": None}


def branch_changes(old: RunConfig, new: RunConfig) -> dict | None:
    """The settings that differ between two configurations when a run could go on with them as a
    branch (only switches that change neither networks nor data); None when a new run is needed."""
    a, b = old.flat(), new.flat()
    changed = {k: b[k] for k in b if a.get(k) != b[k] and k != "iterations"}
    if not changed or type(old.learner) is not type(new.learner) or old.method != new.method:
        return None
    allowed = type(new.learner).branchable() | {"eval_explore"}
    return changed if set(changed) <= allowed else None


def describe(config: RunConfig) -> str:
    """"IUPE on CartPole, seed 0"; a configuration that is no method's preset names its switches."""
    spec = get_env(config.env)
    return f"{configuration_label(config)} on {spec.thesis_name or spec.name}, seed {config.seed}"


@dataclass
class SlotState:
    run: Run | None = None
    identity: dict | None = None
    error: str | None = None  # why no run could be built from the current settings
    step_error: str | None = None  # why the last iteration failed
    target: int = 0  # iteration the user asked to reach
    playing: bool = False  # Run N in progress
    reset_requested: bool = False
    pending_branch: dict | None = None  # switches changed mid-run: {"config", "changes"} until the user chooses
    branch_answer: str | None = None  # "branch" or "new": the user's choice for the pending change
    branch_label: str | None = None  # the name a branched run is saved under
    share_token: tuple | None = None  # (run id, token) of the read-only link
    saved_once: bool = False  # the run is on disk: its ?run= link reopens it
    save_conflict: bool = False  # the last save was refused because another session saved the run
    training: bool = False  # an iteration is training right now (maybe in another thread)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)  # one iteration at a time
    notices: list[str] = field(default_factory=list)
    run_id: str | None = None  # where the run autosaves (ifo.ui.storage)
    user: str | None = None  # autosave under this user; None: no autosave
    save_error: str | None = None
    videos: dict = field(default_factory=dict)  # iteration -> (mp4 bytes, return, steps) of the learner
    expert_videos: dict = field(default_factory=dict)  # (env, episode) -> (mp4 bytes, return, steps)


class _ProgressBar:
    """The Run's progress callback, drawn into one placeholder. Streamlit raises its rerun/stop
    requests at st.* calls; inside Run.step() we hold them back and re-raise after the step."""

    def __init__(self, area, run: Run, on_phase=None):
        self.area, self.total = area, run.config.iterations
        self.run = run
        self.phases = run.phases()
        self.on_phase = on_phase
        self.done = 0.0
        self.deferred: BaseException | None = None

    def show(self, fn, *args, **kwargs) -> None:
        if self.deferred is not None:
            return
        try:
            fn(*args, **kwargs)
        except ScriptControlException as e:
            self.deferred = e

    def __call__(self, phase: str, iteration: int) -> None:
        # the run's own phases (a method that skips some does not jump); never moves the bar back
        names = self.phases
        self.done = max(self.done, names.index(phase) / len(names) if phase in names else 0.0)
        step = names.index(phase) + 1 if phase in names else 0
        text = f"Iteration {iteration} of {self.total}, step {step} of {len(names)}: {self.run.phase_text(phase)}"
        self.show(self.area.progress, self.done, text=text)
        if self.on_phase is not None:
            self.show(self.on_phase, phase, iteration)


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
        if s.run is not None and s.run.config.demos and "demos" not in choice.values:
            # a run on the user's own demonstrations: no widget holds the file, the run does
            choice = Choice({**choice.values, "demos": s.run.config.demos})
        try:
            config = choice.config()
        except ValueError as e:
            s.error, s.playing = f"These settings cannot make a run: {e}", False
            return None
        spec = get_env(config.env)
        if spec.registered and not config.demos:  # a researcher's own environment (IFO_LAB_ENVS)
            s.error, s.playing = (f"IfO Lab ships no demonstrations for {spec.thesis_name}, an environment of "
                                  "your own: upload yours on *Your runs* and press **Train** there; the run then "
                                  "opens here."), False
            return None
        identity = _identity(config)
        if identity != s.identity and not s.reset_requested and s.run is not None and s.run.records:
            changes = branch_changes(s.run.config, config)
            answer, s.branch_answer = s.branch_answer, None
            if changes and answer == "branch":
                return self._branch(config, changes)
            if changes and answer != "new":  # ask first: go on from here as a branch, or start again?
                s.pending_branch = {"config": config, "changes": changes}
                return s.run
        s.pending_branch = None
        if identity == s.identity and not s.reset_requested:
            if s.run is not None:
                s.error = None  # an earlier impossible setting was put right
            if s.run is not None and s.run.config.iterations != config.iterations:
                s.run.config = replace(s.run.config, iterations=config.iterations)  # keep the records
                s.target = min(s.target, config.iterations)
            return s.run
        previous, previous_saved = s.run, s.user is not None and s.save_error is None
        s.reset_requested = s.playing = False
        s.run, s.identity, s.error, s.step_error, s.target, s.branch_label = None, identity, None, None, 0, None
        s.run_id, s.save_error, s.videos = storage.new_run_id(config), None, {}
        s.saved_once = s.save_conflict = False
        with st.spinner(f"Preparing a new run ({describe(config)}): loading the demonstrations "
                        "and collecting random transitions..."):
            try:
                s.run = Run(config, **storage.run_services())
            except Exception as e:  # a missing demonstrations file, an impossible combination, ...
                if isinstance(e, ValueError):  # DemoError and bad settings: the message says it all
                    log.warning("could not build a run: %s", e)
                else:
                    log.exception("could not build a run")
                s.error = f"Could not start a run of {describe(config)}: {e}"
                return None
        if previous is not None and previous.records:
            where = "is kept in Your runs" if previous_saved else "was not saved"
            s.notices.append(f"New run: {describe(config)}. The previous run "
                             f"({describe(previous.config)}, {previous.iteration} iterations) {where}.")
        return s.run

    def _branch(self, config: RunConfig, changes: dict) -> Run | None:
        """Continue the current run from its iteration with `changes`: a new run (saved apart) that shares
        its I_pre, models and records so far."""
        s = self.state
        parent = s.run
        with st.spinner("Branching the run: the same I_pre and models, the new switches from here on..."):
            try:
                branch = parent.branch(**changes)
            except Exception as e:  # noqa: BLE001 - shown, the current run stays
                log.exception("could not branch")
                s.error = f"Could not branch the run: {e}"
                return parent
        s.run, s.identity, s.pending_branch = branch, _identity(config), None
        s.run_id, s.save_error, s.videos, s.target, s.playing = storage.new_run_id(config), None, {}, branch.iteration, False
        s.branch_label = f"{describe(config)}, branched from {describe(parent.config)} at iteration {parent.iteration}"
        s.notices.append(f"Branched at iteration {parent.iteration}: {', '.join(f'{k} = {v}' for k, v in changes.items())}."
                         " The run before the change is kept in Your runs.")
        self.save()
        return branch

    def share_link(self) -> str | None:
        """A read-only link to the saved run (the same every time), or None before its first save."""
        s = self.state
        if s.run is None or s.run.iteration == 0 or s.user is None or s.save_error is not None:
            return None
        if s.share_token is None or s.share_token[0] != s.run_id:
            s.share_token = (s.run_id, storage.share_run(s.user, s.run_id))
        from urllib.parse import urlsplit

        here = urlsplit(st.context.url or "http://localhost:8501/")
        return f"{here.scheme}://{here.netloc}/watch?{storage.SHARE_PARAM}={s.share_token[1]}"

    def answer_branch(self, answer: str) -> None:
        """The user's choice for a pending switch change: "branch" (go on from here) or "new" (start again)."""
        self.state.branch_answer = answer

    def adopt(self, run: Run, run_id: str, key: str) -> None:
        """Make a loaded run this slot's run, and point the settings widgets (`key`) at it, so
        the next `ensure` keeps it."""
        s = self.state
        choice = Choice.from_config(run.config)
        set_widgets(key, choice)
        s.run, s.identity, s.run_id = run, _identity(choice.config()), run_id
        s.error = s.step_error = s.save_error = None
        s.target, s.playing, s.reset_requested, s.videos = run.iteration, False, False, {}
        s.pending_branch, s.branch_label, s.saved_once, s.save_conflict = None, None, True, False

    def open_from_url(self, key: str) -> None:
        """If the URL names a saved run (`?run=<id>`) of this page's user that this slot does
        not hold, load it (before the settings widgets are drawn)."""
        s = self.state
        run_id = st.query_params.get("run")
        if not run_id or run_id == s.run_id or not storage.valid_user(s.user):
            return
        try:
            path = storage.run_path(s.user, run_id)
            if not (path / "LATEST").exists():
                raise FileNotFoundError("it is not among your saved runs")
            with st.spinner("Opening the saved run..."):
                run = Run.load(path, **storage.run_services())
        except Exception as e:  # a deleted run, a foreign link, an old format
            log.warning("could not open run %r: %s", run_id, e)
            s.notices.append(f"Could not open the saved run {run_id}: {e}")
            del st.query_params["run"]
            return
        self.adopt(run, run_id, key)
        s.notices.append(f"Opened the saved run {describe(run.config)} at iteration {run.iteration}.")

    def sync_url(self) -> None:
        """Keep `?run=` naming the current run once it has been saved (reloading the page reopens it, also
        after a later save was refused)."""
        s = self.state
        saved = s.run is not None and s.user is not None and s.saved_once
        if saved and st.query_params.get("run") != s.run_id:
            st.query_params["run"] = s.run_id
        elif not saved and "run" in st.query_params:
            del st.query_params["run"]

    def save(self) -> None:
        s = self.state
        if s.user is None or s.run is None or s.run_id is None:
            return
        try:
            storage.save_run(s.run, s.user, s.run_id, label=s.branch_label or describe(s.run.config))
            s.save_error, s.save_conflict, s.saved_once = None, False, True
        except checkpoint.RunChanged:  # two tabs on one run: the other saved first; nothing is lost
            s.save_conflict = True
            s.save_error = ("Another tab or session saved this run meanwhile, so this iteration was not saved over "
                            "it. Reopen the run from its latest save, or keep what you see here as a copy.")
        except Exception as e:  # a full disk must not stop the lesson
            log.exception("autosave failed")
            s.save_error = f"Could not save the run: {getattr(e, 'reason', None) or e}"

    def reopen_latest(self, key: str) -> None:
        """After a refused save: load the run as another session last saved it."""
        s = self.state
        run = Run.load(storage.run_path(s.user, s.run_id), **storage.run_services())
        self.adopt(run, s.run_id, key)

    def keep_as_copy(self) -> None:
        """After a refused save: save what this session has as a run of its own."""
        s = self.state
        s.run.parent, s.run_id = None, storage.new_run_id(s.run.config)
        s.branch_label = f"{describe(s.run.config)} (a copy made when another tab saved the same run)"
        self.save()

    @property
    def run_id(self) -> str | None:
        return self.state.run_id

    # ------------------------------------------------------------------ videos
    @property
    def videos(self) -> dict:
        return self.state.videos

    def render_videos(self, episode: int = 0, iteration: int | None = None) -> None:
        """Record the policy after `iteration` (default: the latest; and the expert, once per environment)
        on evaluation episode `episode`, as MP4, cached per iteration."""
        from ifo.video import expert_rollout_frames, frames_to_mp4, policy_rollout_frames

        s, run = self.state, self.state.run
        iteration = iteration or run.iteration
        fps = 6 if run.spec.is_maze else 30
        with s.lock:  # never while the run trains in another thread
            frames, ret = policy_rollout_frames(run, episode, iteration=iteration)
        s.videos[iteration] = (frames_to_mp4(frames, fps=fps), ret, len(frames) - 1)
        ekey = (run.spec.name, episode)
        if ekey not in s.expert_videos:
            try:
                frames, ret = expert_rollout_frames(run.spec.name, episode)
                s.expert_videos[ekey] = (frames_to_mp4(frames, fps=fps), ret, len(frames) - 1)
            except FileNotFoundError as e:  # no expert weights shipped for this task
                log.warning("no expert video: %s", e)
                s.expert_videos[ekey] = None

    def expert_video(self, episode: int = 0):
        run = self.state.run
        return self.state.expert_videos.get((run.spec.name, episode)) if run is not None else None

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

    def request_run_to_end(self) -> None:
        s = self.state
        if s.run is not None:
            self.request_run(s.run.config.iterations - self._base())

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
    def advance(self, area, on_phase=None) -> None:
        """Train one iteration if the run is behind its target, showing progress in `area`
        (an st.empty()) and calling `on_phase(phase, iteration)` as each phase starts. A Play
        that reaches its target (or fails) stops: `playing` turns False, and so does `tick`."""
        s = self.state
        if s.run is None:
            return
        bar = _ProgressBar(area, s.run, on_phase)
        # Streamlit starts a full rerun without waiting for a fragment run it cancels, so two
        # threads of this session can get here at once: one trains, the other waits for it.
        _acquire(s.lock, bar, area, "Finishing the iteration in progress...")
        try:
            self._advance_locked(bar, area)
        finally:
            s.lock.release()

    def _advance_locked(self, bar: "_ProgressBar", area) -> None:
        s, run = self.state, self.state.run
        if run.iteration >= min(s.target, run.config.iterations):
            s.playing = False
            return
        if run.step_if_cached() is not None:  # computed ahead, or by another session following the lesson
            if (ahead := server_ahead()) is not None:
                ahead.stepped()
            self.save()
            self._stop_play_at_target(run)
            return
        ahead, key = server_ahead(), run.next_key() if run.lineage is not None else None
        with ahead.stepping(key) if ahead is not None else nullcontext():  # nothing else trains ahead meanwhile
            if ahead is not None and key is not None and ahead.working_on(key):
                bar.show(area.info, f"Iteration {run.iteration + 1} was already being computed ahead; finishing it...")
            self._train(run, bar, area)
        if bar.deferred is not None:  # the click that arrived during the iteration: handle it now
            raise bar.deferred
        self._stop_play_at_target(run)

    def _train(self, run: Run, bar: "_ProgressBar", area) -> None:
        """The next iteration of `run` (trained here, or taken from the cache once whoever trains it is done)."""
        s = self.state
        _acquire(_TRAININGS, bar, area, "Waiting for other sessions' training to finish...")
        s.training = True
        try:
            run.progress = bar
            run.step()
            run.progress = None
            self.save()
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

    def _stop_play_at_target(self, run: Run) -> None:
        s = self.state
        if run.iteration >= min(s.target, run.config.iterations):
            s.playing = False

    def compute_ahead(self) -> None:
        """At rest after a Step (not playing, no error, not training): the next iteration trains in the
        background while the class looks at this one. The page calls it once it is drawn, so the drawing
        has the machine first; asking again for the same iteration costs nothing."""
        s, ahead = self.state, server_ahead()
        if ahead is None or s.run is None or not s.run.records or s.playing or s.step_error is not None:
            return
        if s.lock.acquire(blocking=False):  # not while an iteration of this run trains in another thread
            try:
                ahead.request(s.run)
            finally:
                s.lock.release()


def _acquire(lock, bar: _ProgressBar, area, message: str) -> None:
    """Take `lock`, showing `message` while waiting; a click while waiting abandons the wait."""
    if lock.acquire(blocking=False):
        return
    while bar.deferred is None and not lock.acquire(timeout=0.25):
        bar.show(area.info, message)
    if bar.deferred is not None:
        raise bar.deferred


def hidden() -> set[str]:
    """What a lesson hides: `?hide=settings,diagram,rollout` (controls, panels by registry key)."""
    return {h.strip().lower() for h in st.query_params.get("hide", "").split(",") if h.strip()}


def lesson_parts() -> dict[str, str]:
    """What a lesson link can hide (`?hide=`): the page's controls and each panel, by key -> title."""
    from ifo.ui.registry import PANELS

    return {"settings": "the settings sidebar", "controls": "the Step/Run/Reset buttons", "diagram": "the loop diagram",
            "metrics": "the metrics row", **{p.key: f"panel: {p.title}" for p in PANELS}}


def lesson_link(hide: list[str]) -> str:
    """This page's link with its current settings and `hide`, without the user's id or run."""
    from urllib.parse import urlencode, urlsplit

    here = urlsplit(st.context.url or "http://localhost:8501/step")
    params = {k: st.query_params.get(k) for k in st.query_params
              if k not in (storage.USER_PARAM, "run", "hide", storage.SHARE_PARAM)}
    if hide:
        params["hide"] = ",".join(hide)
    return f"{here.scheme}://{here.netloc}{here.path}" + (f"?{urlencode(params)}" if params else "")
