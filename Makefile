# The project's own virtual environment (make install makes it), with the versions requirements.lock pins:
# every target runs in it.  PYTHON=python3 runs them in an environment of your own instead.
BASE_PYTHON ?= python3
VENV ?= .venv
PYTHON ?= $(VENV)/bin/python
LOCK = requirements.lock
# pytest-xdist: one worker process per core, at most 4 (each holds its own JAX and simulators; the JAX
# compilation cache is shared).  PARALLEL= runs the tests in one process, as does an install without it.
PARALLEL ?= $(shell $(PYTHON) -c "import xdist" 2>/dev/null && echo "-n auto --maxprocesses 4 --dist worksteal")

.PHONY: help install lock format lint test test-all bench bench-kernels bench-train bench-dynamics bench-periodic study-fidelity study-reference study-wellposed study-round study-stability study-incompressible docs simulate run tutorial repro-translation repro-rotation-single repro-rotation-double repro-shape-matching repro-digital-mnist repro-dynamic-follow repro-dynamic-energy repro-periodic-poisson repro-periodic-poisson-amortised study-min-feature repro-all repro-check verify settings-reference clean

help:               ## list the targets (the default: plain `make` installs nothing)
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed -E 's/:[^#]*## /\t/' | expand -t 24

install:            ## a virtual environment in .venv with the locked versions the tests passed with, and nma in it (editable)
	@$(BASE_PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11) and "nma needs Python 3.11 or newer; this is " + sys.version.split()[0] + " (make install BASE_PYTHON=python3.12)")'
	test -x $(VENV)/bin/python || $(BASE_PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r $(LOCK)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps -e .

lock:               ## refresh requirements.lock to the newest versions pyproject.toml allows, install them and run the fast suite on them
	test -x $(VENV)/bin/python || $(BASE_PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check "uv>=0.9,<1"
	$(VENV)/bin/python -m uv pip compile pyproject.toml --extra test --extra docs --universal --python-version 3.11 --fork-strategy fewest \
		--upgrade --quiet --custom-compile-command "make lock" -o $(LOCK)
	$(MAKE) install
	$(MAKE) test PYTHON=$(VENV)/bin/python

format:             ## format the code to the project's width (ruff, 100 columns, pyproject.toml)
	$(PYTHON) -m ruff format nma experiments tests

lint:               ## check the format and the lint rules (the fast suite runs this too)
	$(PYTHON) -m ruff format --check nma experiments tests
	$(PYTHON) -m ruff check nma experiments tests

test:               ## fast tests (the CI run), on up to 4 worker processes
	$(PYTHON) -m pytest -q $(PARALLEL)

test-all:           ## every test, the slow physics checks included
	$(PYTHON) -m pytest -q -m "" $(PARALLEL)

bench:              ## solver speed per scene at the paper discretisation, linear backends -> outputs/bench/solver.json
	$(PYTHON) experiments/bench_solver.py

bench-kernels:      ## one Newton linearisation per scene, elements in cache-sized chunks vs all at once -> outputs/bench/kernels.json
	$(PYTHON) experiments/bench_kernels.py --repeats 7

bench-train:        ## training-step speed per scene: threads vs one, compile, cache -> outputs/bench/train.json
	$(PYTHON) experiments/bench_train.py

bench-dynamics:     ## a time step against a static solve; 100 steps forward + adjoint of the translation -> outputs/bench/dynamics.json
	$(PYTHON) experiments/bench_dynamics.py

bench-periodic:     ## one periodic solve of the 2 x 2 square array against the finite block of the same cells -> outputs/bench/periodic.json
	$(PYTHON) experiments/bench_periodic.py

study-fidelity:     ## speed against accuracy per scene; the fronts fidelity=auto reads -> outputs/studies/fidelity/, nma/data/fidelity/ (STUDY_ARGS=--unpinned: the well-posed variants)
	$(PYTHON) experiments/fidelity_study.py $(STUDY_ARGS)

study-reference:    ## is the fidelity study's reference converged? refinement to 17x5, Richardson -> outputs/studies/fidelity/*.convergence.* (STUDY_ARGS="--unpinned --grading 2")
	$(PYTHON) experiments/fidelity_study.py --convergence $(STUDY_ARGS)

study-wellposed:    ## the well-posed variants (no pins), knots graded 3, refinement 14 -> 26 x 5 -> outputs/studies/fidelity/*_unpinned_graded3.convergence.* (hours: a rotation 35-50 min; shape matching's draw does not solve at 23 and 26 x 5)
	$(PYTHON) experiments/fidelity_study.py --convergence --unpinned --grading 3 --ladder 14 17 20 23 26 $(STUDY_ARGS)

study-round:        ## the well-posed variants with round pore corners (scene.round_pore_corners), knots graded 3, refinement 11 -> 20 x 5 -> outputs/studies/fidelity/*_unpinned_round_graded3.convergence.* (STUDY_ARGS="--scenes shape_matching --draws 1 --actuation 0.125")
	$(PYTHON) experiments/fidelity_study.py --convergence --unpinned --round-corners --grading 3 --ladder 11 14 17 20 $(STUDY_ARGS)

study-stability:    ## solver outcome at the extremes (nu, radii, corners, d_max) per scene -> outputs/studies/stability/
	$(PYTHON) experiments/stability_map.py

INCOMPRESSIBLE = --formulation mixed --inversion-barrier 0.5 --contact --corrector trust_region --max-step-iters 300 --nus 0.499
study-incompressible: ## the map at nu 0.499 with the locking-free model, its settings for it (~15 min), then its states that are not physical again at 8 x 5 (~30 min) -> outputs/studies/stability_incompressible{,_8x5}/
	$(PYTHON) experiments/stability_map.py $(INCOMPRESSIBLE) --max-iters 1000 --out outputs/studies/stability_incompressible
	$(PYTHON) experiments/stability_map.py $(INCOMPRESSIBLE) --max-iters 3000 --mesh 8 5 \
		--not-physical-in outputs/studies/stability_incompressible --out outputs/studies/stability_incompressible_8x5

simulate:           ## one forward solve of the translation scene
	$(PYTHON) -m nma.simulate scene=translation actuation=[1.0,-0.5]

run:                ## train the default experiment (translation, 100 steps)
	$(PYTHON) -m nma.run

tutorial:           ## docs/tutorials/own-scene-and-task.md: the strip's tasks posed in YAML (joint, frozen; a pore on demand) -> outputs/tutorial/
	$(PYTHON) -m nma.run task=strip_spread scene=strip hydra.run.dir=outputs/tutorial/joint
	$(PYTHON) -m nma.run task=strip_spread scene=strip trainer.freeze_geometry=true hydra.run.dir=outputs/tutorial/frozen
	$(PYTHON) -m nma.run task=strip_pore scene=strip hydra.run.dir=outputs/tutorial/pore

repro-translation:  ## paper translation: joint design vs frozen baseline -> outputs/repro/translation/
	$(PYTHON) experiments/repro.py translation --baseline-steps 80 $(REPRO_ARGS)

repro-rotation-single: ## paper rotation, single stick: joint (5x2, refined at 8x2 then 11x2 with contact) vs frozen -> outputs/repro/rotation_single/
	$(PYTHON) experiments/repro.py rotation_single --baseline-steps 60 $(REPRO_ARGS)

repro-rotation-double: ## paper rotation, double: joint (5x2, refined at 8x2 with contact) vs frozen -> outputs/repro/rotation_double/
	$(PYTHON) experiments/repro.py rotation_double --baseline-steps 60 $(REPRO_ARGS)

repro-digital-mnist: ## digital MNIST: lookup table, network fit, end-to-end fine-tuning -> outputs/repro/digital_mnist/
	$(PYTHON) experiments/repro.py digital_mnist $(REPRO_ARGS)

repro-shape-matching: ## pore shape matching (with contact): joint vs frozen vs no actuation -> outputs/repro/shape_matching/
	$(PYTHON) experiments/repro.py shape_matching --baseline-steps 250 $(REPRO_ARGS)

repro-dynamic-follow: ## in time: the pointer follows circles, joint design vs frozen baseline -> outputs/repro/dynamic_follow/
	$(PYTHON) experiments/repro.py dynamic_follow --baseline-steps 60 $(REPRO_ARGS)

repro-dynamic-energy: ## in time: an impulse's kinetic energy focused in a corner, joint vs frozen -> outputs/repro/dynamic_energy/
	$(PYTHON) experiments/repro.py dynamic_energy --baseline-steps 60 $(REPRO_ARGS)

repro-periodic-poisson: ## periodic: one 2 x 2 cell's pore radii trained to Poisson's ratio -0.5 at 10% compression vs circular holes -> results/periodic_poisson/
	$(PYTHON) experiments/periodic_repro.py periodic_poisson $(REPRO_ARGS)

repro-periodic-poisson-amortised: ## periodic: a network from the target Poisson's ratio to the pore, on held-out targets, vs circular holes -> results/periodic_poisson_amortised/
	$(PYTHON) experiments/periodic_repro.py periodic_poisson_amortised $(REPRO_ARGS)

study-min-feature:  ## translation and double rotation retrained with a 0.8 mm minimum feature at 2 mm per unit, vs unbounded -> results/*_min_feature/
	$(PYTHON) experiments/min_feature.py translation
	$(PYTHON) experiments/min_feature.py rotation_double

repro-all:          ## every reproduction above, in two lanes side by side (one Newton thread each): the whole paper
	$(PYTHON) experiments/repro_all.py

repro-check:        ## results/ against its record (results/record.json): exit 1 where a result got worse than its noise band
	$(PYTHON) experiments/guard.py

verify:             ## verification benchmarks (cantilever frequencies, Cook's membrane, St Venant-Kirchhoff, Turek-Hron CSM1/2, Mooney-Rivlin block, Treloar fits) against their references; exit 1 where one leaves its tolerance -> results/verification/
	$(PYTHON) experiments/verify.py

settings-reference:  ## docs/reference/settings.md from the config schema (a test fails where it is stale)
	$(PYTHON) experiments/settings_reference.py

docs:               ## the documentation site (MkDocs, API reference from docstrings), warnings as errors -> outputs/site/
	NO_MKDOCS_2_WARNING=1 $(PYTHON) -m mkdocs build --strict --site-dir outputs/site

clean:              ## remove outputs/ results and __pycache__
	rm -rf outputs/simulate outputs/bench outputs/runs outputs/multirun outputs/repro outputs/tutorial outputs/debug outputs/site .pytest_cache
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
