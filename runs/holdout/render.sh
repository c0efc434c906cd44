#!/bin/bash
# the Cycles holdout split (stop 38): scene kinds written after the test set had been read
# (blender_scene.CYCLES_HOLDOUT_KINDS). Resumable: rerun to render what is missing.
echo "start $(date +%T)"
nice -n 10 .venv/bin/jnds dataset --out data --split holdout --engine cycles --jobs 1
echo "done $(date +%T)"
