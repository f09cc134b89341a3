"""ifo: a compact PyTorch library for Imitation Learning from Observation.

Layers: `ifo.envs` (environments, goal tests, rollouts), `ifo.data` (demonstrations,
I_pre), `ifo.nets` (IDM and policy networks), `ifo.components` (training, exploration,
sampling), `ifo.methods` (which components each method switches on), `ifo.run` (the
one loop, stepped iteration by iteration), `ifo.metrics`, `ifo.figures`, `ifo.cli`.
The library never imports streamlit.
"""
__version__ = "0.1.0"
