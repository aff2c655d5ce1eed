#!/usr/bin/env bash
# Makes the GIFs of README.md and docs/ (run from the repository root, after `pip install -e .`).
# docs/demo.gif: the built-in demo scene, its first 4 worlds (box masses differ per
# world) tiled 2 x 2, 3 simulated seconds in real time (a frame every 2 steps at 30 fps).
# docs/level.gif: the shipped level platformer1, one world, 5 simulated seconds.
set -euo pipefail
jaxchain demo --batch 4 --steps 180 --chunk 60 --no-progress \
  --gif docs/demo.gif --gif-worlds 4 --gif-size 72x120 --gif-every 2 --gif-fps 30
jaxchain demo --level platformer1 --batch 1 --steps 300 --chunk 60 --no-progress \
  --gif docs/level.gif --gif-worlds 1 --gif-size 96x160 --gif-every 3 --gif-fps 20
