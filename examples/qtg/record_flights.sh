#!/bin/sh
# Regenerates the flight tests of examples/qtg/bo105_80kt.toml: 3-2-1-1s, doublets and steps of 1 deg on
# each control of the Bo105 flight-test stand-in at 80 kt (docs/vehicles.md), 8 s at 100 Hz from
# trim, each with its own seed (turbulence and sensor noise). Run from the repository root with
# flightgp on PATH (. .venv/bin/activate), or FLIGHTGP=".venv/bin/flightgp" sh examples/qtg/record_flights.sh.
set -e
FLIGHTGP=${FLIGHTGP:-flightgp}
OUT=examples/qtg/flights
seed=1
for input in theta_0 theta_1s theta_1c theta_0T; do
    $FLIGHTGP record --vehicle bo105-80kt-flight --input "$input" --manoeuvre 3211 --step-time 0.4 \
        --amplitude-deg 1 --start 1 --duration 8 --seed "$seed" --out "$OUT/${input}_3211.csv"
    $FLIGHTGP record --vehicle bo105-80kt-flight --input "$input" --manoeuvre doublet --step-time 0.5 \
        --amplitude-deg 1 --start 1 --duration 8 --seed "$((seed + 1))" --out "$OUT/${input}_doublet.csv"
    seed=$((seed + 2))
done
# Steps of 1 deg on each control, held from 1 s (seeds 9-12): the short-term responses.
for input in theta_0 theta_1s theta_1c theta_0T; do
    $FLIGHTGP record --vehicle bo105-80kt-flight --input "$input" --manoeuvre step \
        --amplitude-deg 1 --start 1 --duration 8 --seed "$seed" --out "$OUT/${input}_step.csv"
    seed=$((seed + 1))
done
