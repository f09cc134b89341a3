"""Watch a shared run: what a student sees from a teacher's read-only link (`?share=<token>`).

Thin by design: the saved run's records (ifo.checkpoint, read only) -> the same counter, slider,
loop diagram and panels as the step page (ifo.ui.panels.show_records). Nothing here can change
the teacher's run; "Make my own copy" copies it into the student's own runs, to train further.
A small fragment looks at the run's latest checkpoint every second and redraws the page
when the teacher has stepped.
"""
import streamlit as st

from ifo import checkpoint
from ifo.methods import get_method
from ifo.runtime import limit_threads
from ifo.ui import storage
from ifo.ui.panels import PanelContext, show_records
from ifo.ui.session import hidden

limit_threads()
# How often each watching page asks for a newer checkpoint: a class sees the teacher's Step within about
# this plus the thirty redraws (scripts/load_test.py --mode watch); one ask costs the server a small read.
FOLLOW_SECONDS = 1.0
WATCHED = "watch.token"  # the shared run this session watches
hide = hidden()
st.title("Watch a shared run")
user = storage.current_user()
# The link's token, else the run this session last watched: the sidebar's link and the browser's Back
# button come here without `?share=` (Streamlit's navigation drops query params), and a student who
# looked at another page mid-lesson should find the teacher's run again, not an empty page.
token = st.query_params.get(storage.SHARE_PARAM) or st.session_state.get(WATCHED)
if not token:
    st.info("Open the link your teacher shared (it ends with `?share=...`) to watch their run here.")
    st.stop()
try:
    saved = storage.shared_run(token)
    config = checkpoint.read_config(saved.path)
    latest = checkpoint.latest(saved.path)
except (ValueError, FileNotFoundError, OSError) as e:  # a bad or stale link, a deleted or damaged run
    if st.session_state.get(WATCHED) == token:
        del st.session_state[WATCHED]  # not offered again
    st.error(f"Could not open this shared run: {getattr(e, 'reason', None) or e}")
    st.stop()
st.session_state[WATCHED] = token
if st.query_params.get(storage.SHARE_PARAM) != token:
    st.query_params[storage.SHARE_PARAM] = token  # the address bar is the link again, to pass on or reload

key = f"watch.{token}"
if st.session_state.get(f"{key}.checkpoint") != latest:  # read the records once per checkpoint
    st.session_state[f"{key}.records"] = checkpoint.read_records(saved.path)
    st.session_state[f"{key}.checkpoint"] = latest
records = st.session_state[f"{key}.records"]

left, right = st.columns([3, 1], vertical_alignment="center")
left.markdown(f"You are watching **{saved.label}**, read-only: the teacher's Steps appear here as they happen.")
if right.button("Make my own copy", key="watch.copy", type="primary", icon=":material/content_copy:",
                help="Copy this run into your own runs, to step, branch and train it yourself."):
    try:
        new_id = storage.copy_shared_run(token, user)
    except (ValueError, OSError) as e:
        st.error(f"Could not copy the run: {e}")
    else:
        st.switch_page("views/step_through.py", query_params={"run": new_id, storage.USER_PARAM: user})


@st.fragment(run_every=FOLLOW_SECONDS)
def follow() -> None:
    """Redraw the page when the teacher's run has a newer checkpoint (cheap otherwise: one small read)."""
    try:
        now = checkpoint.latest(saved.path)
    except (ValueError, OSError):
        return
    if now != latest:
        st.rerun()
    st.caption(f"Live: following the teacher's run ({len(records)} iteration{'s' * (len(records) != 1)} so far).")


follow()
first = records[0] if records else {}
sizes = {"pre_size": first.get("idm", {}).get("train_size"),
         "expert_size": sum(first["idm"]["prediction_counts"]) if "idm" in first else None}
show_records(records, int(config.get("iterations") or len(records)), hide, sizes, (st.empty(), st.empty(), st.empty()),
             lambda shown: PanelContext(None, None, records, shown, config), key="watch",
             layout=get_method(str(config.get("method"))).learner_class.diagram)
if not records:
    st.info("The teacher has not trained an iteration yet: this page follows along as they do.")
