"""Small Streamlit helpers shared by the app's pages.

This package is the only part of `ifo` that imports streamlit: the training library
(`ifo.run`, `ifo.figures`, ...) stays usable without it. Pages stay thin:
widgets (`ifo.ui.settings`) -> RunConfig -> the session's run (`ifo.ui.session`)
-> records -> figures from `ifo.figures` -> screen (`ifo.ui.panels`).
"""
