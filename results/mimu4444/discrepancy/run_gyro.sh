#!/usr/bin/env bash
# The six diagnoses of run.sh with the angular rate taken from the board's gyroscopes (--use-gyro),
# so that the gyroscopes' own scale factor and misalignment can be tried: diagnose_gyro_K.json and
# diagnose_gyro_K.txt. About three and a half minutes with a release build (2026-11-28, a slow machine).
exec "$(dirname "$0")/run.sh" --use-gyro
