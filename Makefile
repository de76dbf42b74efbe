# Two commands set up everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test install bench clean llvm

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(STAMP): $(BIN)/python pyproject.toml
	$(BIN)/pip install --quiet -e ".[test,render]"
	touch $(STAMP)

install: $(STAMP) llvm

# Mitsuba's fast CPU variant (llvm_ad_rgb, `paintjax render`) needs LLVM 17 or newer; Debian bookworm's
# libLLVM 14–16 cannot compile what Dr.Jit emits. Installed here when missing and apt-get can (root);
# otherwise rendering falls back to the slow scalar_rgb variant (nothing fails).
llvm:
	@if ! ls /usr/lib/*/libLLVM*.so* 2>/dev/null | grep -qE 'LLVM(-|\.so\.)(1[7-9]|[2-9][0-9])'; then \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	    echo "installing libllvm19 (Mitsuba's llvm_ad_rgb variant)"; \
	    (apt-get install -y -qq libllvm19 >/dev/null 2>&1 || (apt-get update -qq >/dev/null 2>&1 && apt-get install -y -qq libllvm19 >/dev/null 2>&1)) \
	      || echo "libllvm19 could not be installed: paintjax render uses the slow scalar_rgb variant"; \
	  else echo "no LLVM >= 17 found: paintjax render uses the slow scalar_rgb variant (install libllvm19 for llvm_ad_rgb)"; fi; \
	fi

demo: $(STAMP) llvm
	$(BIN)/paintjax demo

test: $(STAMP) llvm
	$(BIN)/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder -q --durations=40

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV)
