#!/bin/sh
# Regenerate every sample log from its scenario with `ltmap simulate` (deterministic: the same
# files, byte for byte). Run from anywhere: sh sample_logs/make_samples.sh
set -eu
cd "$(dirname "$0")/scenarios"
LTMAP=${LTMAP:-ltmap}
for d in 01_static_object 02_table 03_ball 04_door 05_person 06_house; do
    "$LTMAP" simulate "$d/scenario.yaml" -o "$d/log.mcap"
done
# scenario 1 also as a ROS 1 bag and a ROS 2 bag folder (same ground truth)
"$LTMAP" simulate 01_static_object/scenario.yaml -o 01_static_object/log.bag --format ros1
# (--force: the committed log_ros2/ predates ltmap_manifest.json, so ltmap does not know it as its own)
"$LTMAP" simulate 01_static_object/scenario.yaml -o 01_static_object/log_ros2 --format ros2 --force
du -sh .
