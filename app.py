"""IfO Lab: the Streamlit entry point. Run with `streamlit run app.py`.

Navigation, the page config and a landing page for a class. Each activity is a page in
`views/`; the training itself lives in the `ifo` library, which never imports streamlit.
Set IFO_LAB_FAST=1 for tiny runs (used by the tests; see `ifo.ui.settings`).
"""
import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # the maze renders with pygame, headless

import streamlit as st  # noqa: E402

from ifo.methods import METHODS, PLANNED  # noqa: E402
from ifo.runtime import limit_threads  # noqa: E402
from ifo.ui import storage  # noqa: E402
from ifo.ui.lessons import lessons  # noqa: E402

limit_threads()
ICON = os.path.join(os.path.dirname(os.path.abspath(__file__)), "assets", "icon.png")  # local: nothing fetched
st.set_page_config(page_title="IfO Lab", page_icon=ICON, layout="wide")

# The pages live in views/, not pages/: with a pages/ folder Streamlit treats a server's first session
# as a v1 multipage app, and a deep link there (/runs, /watch?share=..., /resilience) ran the page
# alone, without this file, its sidebar listing file names (streamlit/streamlit#9992).
step_page = st.Page("views/step_through.py", title="Step through a run", icon=":material/skip_next:",
                    url_path="step")


def landing() -> None:
    st.title("IfO Lab")
    st.subheader("Imitation Learning from Observation, one iteration at a time")
    family = ", ".join(m.title for m in METHODS.values() if m.learner == "bco")
    others = ", ".join(m.title for m in METHODS.values() if m.learner != "bco")
    planned = f" Planned: {', '.join(p.upper() for p in PLANNED)}." if PLANNED else ""
    st.markdown(
        "In **imitation learning from observation** (IfO) an agent learns a task by watching an expert, "
        "but the demonstrations hold only what the expert *saw* (its states), never which actions it took.\n\n"
        "The agent first acts at random and learns an **inverse dynamics model** (IDM) that guesses which action "
        "leads from one state to the next. It uses the IDM to label the expert's state pairs with guessed actions, "
        "trains its policy to copy those labels, then runs the policy and feeds its own new experience back to "
        "the IDM: this is the **BCO loop**, and one press of *Step* is one turn of it.\n\n"
        f"**{family}** are that one loop with components switched on (iterating, attention, goal-aware "
        "sampling, exploration); BC is the reference that is allowed to see the expert's true actions. "
        f"**{others}** are learners of their own built from the same parts: learning from the agent's own "
        "rewards (CRIL), a discriminator that tells the expert from the agent (SAIL, GAIL, GAIfO), latent "
        f"actions (ILPO).{planned}\n\n"
        "Open *Step through a run*, choose an environment and a method, and press *Step*; or start from one of "
        "the lessons below, each chosen because something visibly happens in it."
    )
    if st.button("Step through a run", key="open_step", type="primary", icon=":material/skip_next:"):
        st.switch_page(step_page)
    lessons(step_page)


@st.cache_resource(show_spinner=False)
def warm_up_process() -> bool:
    """Once per server process, after its first page is drawn (the teacher reads it): the imports the
    step page needs and torch's first-Adam-step cost, which the class's first Step would pay otherwise."""
    import ifo.run  # noqa: F401  the training library: torch, gymnasium, the learners
    import ifo.ui.panels  # noqa: F401  the figures: plotly
    from ifo.components.learning import warm_up

    warm_up()
    return True


# One notion of "who is this" for every page: the `?user=` id, else the one this session already has,
# else a new one; written back into the URL on every page, because sidebar links drop query params.
storage.current_user()
home = st.Page(landing, title="Welcome", icon=":material/school:", default=True)
st.navigation([home, step_page,
               st.Page("views/runs.py", title="Your runs", icon=":material/folder_open:", url_path="runs"),
               st.Page("views/compare.py", title="Compare and ablate", icon=":material/compare_arrows:",
                       url_path="compare"),
               st.Page("views/watch.py", title="Watch a shared run", icon=":material/visibility:",
                       url_path="watch"),
               st.Page("views/resilience.py", title="Sub-optimal experts", icon=":material/trending_down:", url_path="resilience")]).run()
warm_up_process()
