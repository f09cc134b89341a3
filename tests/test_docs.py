"""The documents say which command made each table and figure: those commands must still be commands.

Every `Made with `python -m ifo ...`` in docs/ and README.md is parsed by the command line's own parser
(nothing is trained), and its --table, --envs and --rows must name a table, environments and rows that
exist; a renamed option or row fails here, not on a reader's machine. The tables' statistics (sample sd,
95 % interval, verdicts) are tested here too, since the documents quote them. A table whose trainings ship
(its results file beside it, or the app's Chapter 7 results) is re-rendered from them, training nothing.
"""
import re
import shlex
from collections import Counter
from pathlib import Path

import pytest

from ifo.cli import build_parser
from ifo.reproduce import TABLES, interval95, reproduce, row_labels, verdict

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]
MADE_WITH = re.compile(r"[Mm]ade with `(python -m ifo [^`]+)`")


def documented_commands() -> list[tuple[str, str]]:
    found = []
    for path in DOCUMENTS:
        for command in MADE_WITH.findall(path.read_text(encoding="utf-8")):
            found.append((str(path.relative_to(ROOT)), command))
    return found


def test_the_documents_name_the_commands_that_made_them():
    assert len(documented_commands()) >= 10
    made = {Path(c.split("--out ")[1].split()[0]).name for _, c in documented_commands() if "--out " in c}
    for table in sorted((ROOT / "docs" / "reproduction").glob("*.md")):  # every table file says how it was made
        assert table.name in made, f"{table.name} does not end with the command that made it"


@pytest.mark.parametrize("where,command", documented_commands(), ids=lambda v: v if "/" in v or ".md" in v else None)
def test_a_documented_command_still_parses_and_names_what_exists(where, command):
    argv = shlex.split(command)[3:]  # after "python -m ifo"
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse's way to refuse
        pytest.fail(f"{where}: `{command}` no longer parses (exit {exc.code})")
    table_id = getattr(args, "table", None)
    if table_id is None:
        return
    assert table_id in TABLES, f"{where}: no table {table_id}"
    table = TABLES[table_id]
    for env in (args.envs.split(",") if getattr(args, "envs", None) else []):
        assert env in table.envs, f"{where}: table {table_id} has no column {env}"
    labels = {r.label for r in table.rows}
    for row in (row_labels(args.rows) if getattr(args, "rows", None) else []):
        assert row in labels, f"{where}: table {table_id} has no row {row}"


def test_the_interval_and_the_verdict_claim_only_what_the_seeds_support():
    low, high = interval95([1.0, 2.0, 3.0])
    assert (low, high) == pytest.approx((2.0 - 2.4842, 2.0 + 2.4842), abs=1e-3)  # t(0.975, 2) · 1 / √3
    assert interval95([5.0]) is None and interval95([4.0, 4.0]) == (4.0, 4.0)
    assert verdict([500.0] * 5, 475) == "met"
    assert verdict([480.0, 470.0, 500.0], 475).startswith("met on average")  # the mean clears it, the seeds do not
    assert verdict([400.0, 500.0], 475) == "MISSED"
    assert verdict([490.0], 475) == "met (one seed)"


def test_a_thesis_cell_that_is_a_fill_in_is_marked_and_explained(monkeypatch):
    import ifo.reproduce as reproduce_mod

    monkeypatch.setattr(reproduce_mod, "run_row", lambda *a, **k: {"aer": -100.0, "performance": 1.0, "seconds": 1.0})
    text = reproduce("6.1", seeds=2, envs=["mountaincar"], rows=["ILPO"], log=lambda m: None)
    row = next(line for line in text.splitlines() if line.startswith("| ILPO"))
    assert "| -167.000 (note 1) |" in row
    assert "- Note 1: ILPO's MountainCar AER −167 is a fill-in" in text
    assert "| -100.000 ± 0.000 | [-100.000, -100.000] |" in row


def shipped_results_files(argv: list[str]) -> list[Path]:
    """The files a documented table's trainings ship in: the results file its command names (--store FILE.jsonl), or,
    for a Chapter 7 sweep whose store (runs/sweeps/...) did not ship, the app's results files it wrote them to
    (--ship, assets/resilience/<env>.jsonl). [] when they do not ship."""
    from ifo.reproduce.chapter7 import shipped_results_path

    if argv[:1] != ["bench"] or argv[1:2] not in (["reproduce"], ["resilience"]) or "--store" not in argv:
        return []
    store = ROOT / argv[argv.index("--store") + 1]
    if store.suffix == ".jsonl" and store.is_file():
        return [store]
    if argv[1] == "resilience" and "--ship" in argv:
        return [shipped_results_path(env) for env in argv[argv.index("--envs") + 1].split(",")]
    return []


def shipped_table_commands() -> list[tuple[str, str]]:
    """The documented tables whose trainings ship in the repository."""
    return [(where, command) for where, command in documented_commands()
            if shipped_results_files(shlex.split(command)[3:])]


def test_some_tables_ship_the_results_they_were_made_from():
    kinds = Counter(shlex.split(command)[4] for _, command in shipped_table_commands())
    assert kinds["reproduce"] >= 2 and kinds["resilience"] >= 5


@pytest.mark.parametrize("where,command", shipped_table_commands(), ids=lambda v: v if ".md" in v else None)
def test_a_table_whose_results_ship_is_what_its_command_prints_from_them(where, command, tmp_path, monkeypatch):
    """On a fresh clone the documented command, given the shipped results as its store, trains nothing and prints
    the documented table: every number of it comes from the seeds they list (`bench seeds --store FILE`). Only the
    footer (the command as the process was started) and a Chapter 7 table's "Sweep:" line (what that sweep trained,
    and how fast) differ."""
    from ifo import sweep
    from ifo.cli import main

    def no_training(*args, **kwargs):
        raise AssertionError("the shipped results lack a training of this table")

    monkeypatch.setattr(sweep, "execute", no_training)
    argv = shlex.split(command)[3:]
    shipped = b"".join(path.read_bytes() for path in shipped_results_files(argv))
    store, out = tmp_path / "results.jsonl", tmp_path / "table.md"
    store.write_bytes(shipped)
    argv[argv.index("--store") + 1], argv[argv.index("--out") + 1] = str(store), str(out)
    argv = [a for a in argv if a not in ("--ship", "--local")] + ["--local"]  # --ship would write the app's files
    assert main(argv) == 0
    assert store.read_bytes() == shipped, "the command trained or appended rows"
    body = lambda text: [line for line in text.splitlines()  # noqa: E731
                         if not line.startswith(("Made with `", "Sweep: "))]
    assert body(out.read_text(encoding="utf-8")) == body((ROOT / where).read_text(encoding="utf-8"))


@pytest.mark.parametrize("env,row,longer", [
    ("lunarlander", "IUPE", "tables-7.2-7.6-lunarlander-iupe-100-iterations.jsonl"),
    ("cartpole", "GAIL", "tables-7.2-7.6-cartpole-gail-100-iterations.jsonl"),
    ("acrobot", "GAIL", "tables-7.2-7.6-acrobot-gail-100-iterations.jsonl"),
    ("mountaincar", "GAIL", "tables-7.2-7.6-mountaincar-gail-100-iterations.jsonl"),
    ("mountaincar", "IUPE", "tables-7.2-7.6-mountaincar-iupe-100-iterations.jsonl"),
    ("acrobot", "IUPE", "tables-7.2-7.6-acrobot-iupe-100-iterations.jsonl"),
    ("cartpole", "IUPE", "tables-7.2-7.6-cartpole-iupe-100-iterations.jsonl"),
    ("mountaincar", "BC", "tables-7.2-7.6-mountaincar-bc-100-iterations.jsonl"),
    ("cartpole", "BC", "tables-7.2-7.6-cartpole-bc-100-iterations.jsonl")])
def test_a_longer_shipped_training_begins_with_the_shorter_one_of_the_same_seed(env, row, longer):
    """Same seed, same numbers: IUPE's, GAIL's and BC's schedules do not depend on their round count, so the first 40
    rounds of each shipped 100-round training (docs/reproduction/) are the shipped 40-round training of its level
    and seed (assets/resilience/, the app's page), round by round, though they trained in other sweeps, at other
    commits. `bench seeds --at-iteration 40` on the 100-round file prints the same P and AER as `bench seeds` on
    the 40-round one. Acrobot's and LunarLander's BC files are left out: every seed's 100-round curve differs from
    its 40-round row somewhere in the first 40 rounds (Acrobot's rows trained on another processor; docs/REPRODUCTION.md)."""
    from ifo.reproduce.chapter7 import shipped_results_path
    from ifo.sweep import read_rows

    def curves(path, iterations):  # (table, seed) -> curve, of the row on all the level's demonstrations
        return {(r["spec"]["table"], r["spec"]["seed"]): r["result"]["curve"] for r in read_rows(path)
                if r.get("status") == "done" and r["spec"]["row"] == row and r["spec"]["iterations"] == iterations
                and r["spec"]["env"] == env and set(r["spec"]["settings"]) == {"expert_level"}
                and not r["spec"]["overrides"]}

    long = curves(ROOT / "docs/reproduction" / longer, 100)
    short = curves(shipped_results_path(env), 40)
    assert len(long) == 50 and long.keys() <= short.keys()  # five levels × ten seeds
    differ = sorted(key for key in long if long[key][:40] != short[key])
    assert differ == [], f"(table, seed) whose 100-round training does not begin with its 40-round one: {differ}"
