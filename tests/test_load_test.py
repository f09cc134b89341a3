"""The class benchmark's watch mode (scripts/load_test.py --mode watch), which docs/BENCH.md quotes: it
serves the app, a teacher Steps and shares, the other sessions follow on the watch page as browsers would."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_sessions_watching_a_shared_run_see_every_step_of_the_teacher():
    res = subprocess.run([sys.executable, "scripts/load_test.py", "--client", "protocol", "--mode", "watch",
                          "--sessions", "3", "--steps", "2", "--think", "1", "--timeout", "240", "--step-timeout", "60"],
                         cwd=ROOT, capture_output=True, text=True, timeout=400, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 0, res.stderr[-2000:]
    assert "| 4 / 4 |" in res.stdout, res.stdout  # two watchers saw both of the teacher's Steps
    assert "Errors:" not in res.stdout
    assert "The teacher's own Steps" in res.stdout and "2 sessions watch its shared run" in res.stdout


def test_a_step_redraws_the_run_not_the_whole_page(tmp_path):
    """Pressing Step reruns the part of the step page that shows the run: the counter moves on and the buttons
    are drawn again, while the page's title and the settings in the sidebar are not sent again (each Step of
    each student in a class would pay for them). Spoken to as a browser's page would (scripts/load_test.py)."""
    import asyncio

    sys.path.insert(0, str(ROOT))
    from scripts.app_server import serve_app
    from scripts.load_test import ProtocolSession, step_query

    async def journey(url):
        from streamlit.proto.ForwardMsg_pb2 import ForwardMsg

        session = await ProtocolSession.open(url, step_query("classic", 0), 120)
        sent: list[str] = []
        original = session.ws.recv

        async def recv():  # note every element the server sends from here on
            data = await original()
            msg = ForwardMsg()
            msg.ParseFromString(data)
            if msg.WhichOneof("type") == "delta" and msg.delta.WhichOneof("type") == "new_element":
                sent.append(msg.delta.new_element.WhichOneof("type"))
            return data

        session.ws.recv = recv
        try:
            for want in (1, 2):
                sent.clear()
                await session.step(120)
                assert session.counter == want
                assert "button" in sent, sent  # Step, Run N, Run to the end, Reset: drawn for the new state
                assert "selectbox" not in sent and "heading" not in sent, sent  # no settings, no title
        finally:
            await session.close()

    with serve_app(tmp_path / "server.log", {"IFO_LAB_FAST": "1", "IFO_LAB_RUNS": str(tmp_path / "runs")}) as url:
        asyncio.run(journey(url))


def test_a_session_whose_run_could_not_start_says_so_at_once():
    """The benchmark reports a student whose page could not start a run (the app's "Try again" page) when the page
    is drawn, with what it said, instead of waiting out the whole Step timeout."""
    import asyncio

    import pytest
    from streamlit.proto.ForwardMsg_pb2 import ForwardMsg

    sys.path.insert(0, str(ROOT))
    from scripts.load_test import ProtocolSession

    alert, retry, finished = ForwardMsg(), ForwardMsg(), ForwardMsg()
    alert.delta.new_element.alert.body = "Could not start a run of IUPE on Maze 5x5, seed 101"
    retry.delta.new_element.button.label, retry.delta.new_element.button.id = "Try again", "retry"
    finished.script_finished = ForwardMsg.FINISHED_SUCCESSFULLY

    class Server:  # sends the error page, then nothing more (as the app does)
        def __init__(self):
            self.sent = [m.SerializeToString() for m in (alert, retry, finished)]

        async def recv(self):
            if self.sent:
                return self.sent.pop(0)
            await asyncio.sleep(3600)

    async def step():
        session = ProtocolSession(Server(), "")
        await asyncio.wait_for(session.until(lambda: session.counter == 1, timeout=600), timeout=10)

    with pytest.raises(RuntimeError, match="could not start the run.*Could not start a run of IUPE"):
        asyncio.run(step())
