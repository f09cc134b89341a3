# Two commands for a newcomer: `make run` (the app) and `make test` (the test suite).
# Both create .venv and install requirements.txt on first use (from this machine's
# wheel cache when it has one), so a fresh clone needs nothing installed by hand.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell sha1sum requirements.txt | cut -c1-10)
export SDL_VIDEODRIVER := dummy
export PYTHONPATH := $(CURDIR)

.PHONY: run test setup browser bench clean

run: $(STAMP)
	$(VENV)/bin/streamlit run app.py

test: $(STAMP) browser
	$(PY) -m pytest -q -n 2 --dist loadfile

setup: $(STAMP)

$(STAMP): requirements.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	rm -f $(VENV)/.installed-* && touch $@

# The browser tests and kaleido's figure export drive Debian's chromium; nothing downloads a browser.
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; \
	  else echo "chromium is missing: install Debian's 'chromium' package (sudo apt-get install chromium) for the browser tests"; fi; }

bench: $(STAMP)
	$(PY) -m ifo bench

clean:
	rm -rf $(VENV) .pytest_cache
