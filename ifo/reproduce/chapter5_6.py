"""The thesis's Tables 5.1, 5.2 (ABCO) and 6.1, 6.2 (IUPE): rows, the thesis's numbers, targets."""
from __future__ import annotations

from ifo.reproduce import Row, Table, register

ENVS_5_1 = ("cartpole", "acrobot", "mountaincar", "maze3", "maze5", "maze10")
LOOPS = {"maze3": "maze3-loops", "maze5": "maze5-loops", "maze10": "maze10-loops"}  # the braided twins
WORLDS_NOTE = ("The thesis's maze numbers are shown beside both of our maze worlds: perfect mazes (mazeN) and "
               "braided ones without dead ends (mazeN-loops). The thesis's random and expert returns are closer to "
               "the braided world's (the Random and Expert rows of Table 6.1 show both), so P, which divides by "
               "them, is comparable with the thesis's there rather than in perfect mazes.")


BC, BCO = Row("BC", "bc"), Row("BCO(α)", "bco-alpha")
# ILPO here reads the maze's vector observations (agent cell and walls): our ILPO takes vector states only
ILPO = Row("ILPO", "ilpo", {"obs_mode": "vector"})
# Torabi et al.'s Algorithm 1 keeps I_pre and appends every post-demonstration run (not in the thesis's tables)
BCO_APPEND = Row("BCO(α), appending I_s (Torabi et al.)", "bco-alpha", {"sampling": "append"})
_T51 = {
    "BC": [(1.000, 500.0), (1.071, -83.590), (1.560, -117.720), (-1.207, 0.180), (-0.921, -0.507), (-0.470, -1.000)],
    "BCO(α)": [(1.000, 500.0), (0.980, -117.600), (0.948, -150.000), (0.883, 0.927), (-0.112, 0.104), (-0.416, -0.941)],
    "ILPO": [(1.000, 500.0), (1.067, -85.300), (0.626, -167.000), (-1.711, -0.026), (-0.398, -0.059), (0.257, -0.020)],
    "ABCO": [(1.000, 500.0), (1.086, -77.900), (1.289, -132.300), (1.159, 0.908), (0.960, 0.932), (0.860, 0.784)],
}
_T61 = {
    "Expert": [(1.0, 442.628), (1.0, None), (1.0, -147.265), (1.0, 0.963), (1.0, 0.970), (1.0, 0.981)],
    "Random": [(0.0, 18.700), (0.0, -482.600), (0.0, -200.000), (0.0, 0.557), (0.0, 0.166), (0.0, 0.415)],
    "BC": [(1.135, 500.0), (1.071, -83.590), (1.560, -117.720), (-1.207, 0.180), (-0.921, -0.507), (-0.470, -1.000)],
    "BCO(α)": [(1.135, 500.0), (0.980, -117.600), (0.948, -150.000), (0.883, 0.927), (-0.112, 0.104), (-0.416, -0.941)],
    "ILPO": [(1.135, 500.0), (1.067, -85.300), (0.626, -167.000), (-1.711, -0.026), (-0.398, -0.059), (0.257, -0.020)],
    "IUPE": [(1.135, 500.0), (1.086, -78.100), (1.314, -130.700), (1.361, 0.927), (1.000, 0.971), (1.000, 0.981)],
}


def _by_env(table: dict, envs=ENVS_5_1) -> dict:
    return _with_loops({row: dict(zip(envs, values)) for row, values in table.items()})


def _with_loops(thesis: dict) -> dict:
    """The thesis's maze numbers also beside our braided twin of each maze (it had one maze world)."""
    return {row: {**cells, **{LOOPS[env]: v for env, v in cells.items() if env in LOOPS}}
            for row, cells in thesis.items()}


def _loops_targets(targets: dict) -> dict:
    return {**targets, **{(row, LOOPS[env]): t for (row, env), t in targets.items() if env in LOOPS}}


def _ablation(label: str, attention: bool = False, sampling: str = "none", exploration: bool = False) -> Row:
    return Row(label, "bco-alpha", {"attention": "gated" if attention else "none", "sampling": sampling,
                               "explore_labels": exploration, "explore_rollouts": exploration})


_TABLES = {
    "5.1": Table("Table 5.1: ABCO against related work", ENVS_5_1 + tuple(LOOPS.values()),
                 (BC, BCO, ILPO, Row("ABCO", "abco")), _by_env(_T51), note=WORLDS_NOTE),
    "6.1": Table("Table 6.1: IUPE against related work", ENVS_5_1 + tuple(LOOPS.values()),
                 (Row("Expert", "expert"), Row("Random", "random"), BC, BCO, BCO_APPEND, ILPO,
                  Row("IUPE", "iupe")),
                 _by_env(_T61),
                 targets=_loops_targets({("IUPE", "cartpole"): ("aer", 500.0), ("IUPE", "acrobot"): ("aer", -90.0),
                          ("IUPE", "mountaincar"): ("aer", -140.0), ("IUPE", "maze3"): ("performance", 0.95),
                          ("IUPE", "maze5"): ("performance", 0.95), ("IUPE", "maze10"): ("performance", 0.8)}),
                 note=WORLDS_NOTE,
                 thesis_notes={("ILPO", "mountaincar", "aer"): "ILPO's MountainCar AER −167 is a fill-in: Table 6.1 "
                                "does not print it; it comes from Table 5.1 (and Sec 6.3's text)."}),
    "5.2": Table("Table 5.2: ABCO ablation on the 5×5 maze", ("maze5", "maze5-loops"), (
        _ablation("BCO(α)"), _ablation("BCO(α), appending I_s (Torabi et al.)", sampling="append"),
        _ablation("Attention", attention=True), _ablation("Partial Sampling", sampling="abco"), _ablation("Whole Sampling", sampling="abco-whole"),
        _ablation("ABCO (Attention + Partial Sampling)", attention=True, sampling="abco"),
        _ablation("ABCO (Attention + Whole Sampling)", attention=True, sampling="abco-whole")),
        _with_loops({"BCO(α)": {"maze5": (-0.112, -0.941)}, "Attention": {"maze5": (-0.415, -0.940)},
                     "Partial Sampling": {"maze5": (0.717, 0.716)}, "Whole Sampling": {"maze5": (0.628, 0.676)},
                     "ABCO (Attention + Partial Sampling)": {"maze5": (0.960, 0.932)},
                     "ABCO (Attention + Whole Sampling)": {"maze5": (0.759, 0.755)}}), note=WORLDS_NOTE,
        thesis_notes={(row, env, metric): why for env in ("maze5", "maze5-loops") for row, metric, why in (
            ("BCO(α)", "aer", "BCO's AER −0.941 on the 5×5 maze is likely a typo: it is Table 5.1's 10×10 number; "
                              "Table 5.1 gives BCO 0.104 on 5×5 (with the same P, −0.112)."),)}),
    "6.2": Table("Table 6.2: IUPE ablation on the 10×10 maze", ("maze10", "maze10-loops"), (
        _ablation("BCO(α)"), _ablation("BCO(α), appending I_s (Torabi et al.)", sampling="append"),
        _ablation("Attention", attention=True), _ablation("Sampling", sampling="iupe"),
        _ablation("Exploration", exploration=True), _ablation("Attention + Sampling", attention=True, sampling="iupe"),
        _ablation("Attention + Exploration", attention=True, exploration=True),
        _ablation("Sampling + Exploration", sampling="iupe", exploration=True),
        _ablation("IUPE (Attention + Sampling + Exploration)", attention=True, sampling="iupe", exploration=True)),
        _with_loops({"BCO(α)": {"maze10": (-0.416, -0.941)}, "Attention": {"maze10": (-0.415, -0.940)},
                     "Sampling": {"maze10": (0.534, 0.348)}, "Exploration": {"maze10": (0.734, 0.605)},
                     "Attention + Sampling": {"maze10": (0.367, 0.088)},
                     "Attention + Exploration": {"maze10": (-0.407, -0.921)},
                     "Sampling + Exploration": {"maze10": (0.943, 0.901)},
                     "IUPE (Attention + Sampling + Exploration)": {"maze10": (1.000, 0.981)}}), note=WORLDS_NOTE),
}

for _id, _table in _TABLES.items():
    register(_id, _table)
