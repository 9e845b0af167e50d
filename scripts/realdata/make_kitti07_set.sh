#!/usr/bin/env bash
# Build the "kitti-07" localization test set: 160 consecutive frames of KITTI odometry sequence 07
# (left greyscale camera, a car driving through a residential street), as published in GitHub
# sunglok/3dv_tutorial (bin/data/07), with COLMAP 3.8 (CPU). The frames carry no poses: an SfM
# reconstruction of ALL frames is the pseudo ground truth, scaled to metres by the camera's known
# mounting height above the road (KITTI: 1.65 m).
#
# usage: make_kitti07_set.sh SRC OUT
#   SRC  a checkout of sunglok/3dv_tutorial (bin/data/07/image_0/*.png, bin/data/07/calib.txt)
#   OUT  output folder (created; must not exist or be empty)
#
# Queries: every 8th frame from frame 4 (20 frames spread over the whole drive, turns included);
# the map: the other 140, triangulated with their pseudo-GT poses.
# Steps (as make_lund_set.sh, sequential instead of exhaustive matching, since the frames are a
# video): 1. pseudo ground truth from 8192 SIFT features per frame; 2. the shipped database, SIFT
# capped at MAX_FEATURES; 3. point_triangulator for the map; 4. image_registrator on the queries,
# compared with the pseudo ground truth.
#
# Environment: MAX_FEATURES (default 1024: the shipped database stays near 20 MB), PSEUDO_GT_FEATURES
#              (default 8192), CAMERA_HEIGHT_M (1.65), WORK (scratch folder, default: mktemp -d;
#              a kept one with its pseudo ground truth, sfm/0, reuses it), KEEP_WORK=1 keeps it.
set -euo pipefail

if [[ $# -ne 2 ]]; then
  sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
SRC=$(realpath "$1")
OUT=$(realpath -m "$2")
MAX_FEATURES=${MAX_FEATURES:-1024}
PSEUDO_GT_FEATURES=${PSEUDO_GT_FEATURES:-8192}
CAMERA_HEIGHT_M=${CAMERA_HEIGHT_M:-1.65}
TOOL_DIR=$(dirname "$(realpath "$0")")
TOOL="python3 $TOOL_DIR/colmap_set_tool.py"
FRAMES=$SRC/bin/data/07/image_0
export QT_QPA_PLATFORM=offscreen

[[ -d $FRAMES && -f $SRC/bin/data/07/calib.txt ]] || { echo "bad source folder: $SRC" >&2; exit 2; }
command -v convert >/dev/null || { echo "needs ImageMagick's convert (apt-get install imagemagick)" >&2; exit 2; }
if [[ -e $OUT && -n $(ls -A "$OUT") ]]; then echo "output folder not empty: $OUT" >&2; exit 2; fi
WORK=${WORK:-$(mktemp -d)}
mkdir -p "$OUT/images" "$WORK"
[[ ${KEEP_WORK:-0} == 1 ]] || trap 'rm -rf "$WORK"' EXIT

COMMANDS=$WORK/commands.txt
if [[ -d $WORK/sfm/0 && -f $COMMANDS ]]; then
  sed -i '/colmap mapper/q' "$COMMANDS"  # the reused pseudo ground truth's commands stay
else
  : >"$COMMANDS"
fi
run() {
  echo "$*" | sed -e "s|$OUT|\$OUT|g" -e "s|$SRC|\$SRC|g" -e "s|$WORK|\$WORK|g" \
    -e "s|$TOOL_DIR|scripts/realdata|g" >>"$COMMANDS"
  local step=$2
  [[ $1 == colmap ]] || step=$(basename "$2" .py)_$3
  local log=$WORK/$step.log
  local start=$SECONDS
  if ! "$@" >>"$log" 2>&1; then
    tail -n 30 "$log" >&2
    echo "FAILED: $*" >&2
    exit 1
  fi
  echo "   $step: $((SECONDS - start)) s"
}

# The frames as JPEG (quality 92): a third of the PNGs' bytes.
for png in "$FRAMES"/*.png; do
  convert "$png" -quality 92 "$OUT/images/$(basename "$png" .png).jpg"
done
N_IMAGES=$(ls "$OUT/images" | wc -l)
QUERIES=$(ls "$OUT/images" | awk 'NR % 8 == 5' | paste -sd, -)
echo "== kitti-07: $N_IMAGES frames, queries $QUERIES, scratch $WORK"

# The rectified camera of KITTI's calib.txt (P0): a pinhole without distortion, kept fixed.
read -r FX CX FY CY < <(awk '$1 == "P0:" { print $2, $4, $7, $8 }' "$SRC/bin/data/07/calib.txt")
CAMERA_ARGS=(--ImageReader.single_camera 1 --ImageReader.camera_model PINHOLE
  --ImageReader.camera_params "$FX,$FY,$CX,$CY")
FIXED_CAMERA=(--Mapper.ba_refine_focal_length 0 --Mapper.ba_refine_principal_point 0
  --Mapper.ba_refine_extra_params 0)

# 1. Pseudo ground truth from a richer, unshipped database (the SfM of a kept WORK is reused).
if [[ ! -d $WORK/sfm/0 ]]; then
  run colmap feature_extractor --database_path "$WORK/pseudo_gt.db" --image_path "$OUT/images" \
    "${CAMERA_ARGS[@]}" --SiftExtraction.use_gpu 0 --SiftExtraction.max_num_features "$PSEUDO_GT_FEATURES"
  run colmap sequential_matcher --database_path "$WORK/pseudo_gt.db" --SiftMatching.use_gpu 0 \
    --SiftMatching.guided_matching 1 --SequentialMatching.overlap 20
  mkdir -p "$WORK/sfm"
  run colmap mapper --database_path "$WORK/pseudo_gt.db" --image_path "$OUT/images" \
    --output_path "$WORK/sfm" "${FIXED_CAMERA[@]}"
else
  echo "   reusing the pseudo ground truth in $WORK/sfm/0"
fi
rm -rf "$WORK"/{database.db,database.db-shm,database.db-wal,map_in,map,map_txt,registered,registered_txt,pseudo_gt,pseudo_gt_txt,sfm_txt}
[[ -d $WORK/sfm/0 && ! -d $WORK/sfm/1 ]] || { echo "mapper did not give exactly one model" >&2; exit 1; }
mkdir -p "$WORK/sfm_txt" "$WORK/pseudo_gt" "$WORK/pseudo_gt_txt"
colmap model_converter --input_path "$WORK/sfm/0" --output_path "$WORK/sfm_txt" --output_type TXT >/dev/null 2>&1
read -r SCALE HEIGHT_Q1 HEIGHT_Q3 ROAD_OBSERVATIONS < <($TOOL camera_height_scale "$WORK/sfm_txt" "$CAMERA_HEIGHT_M")
echo "python3 scripts/realdata/colmap_set_tool.py camera_height_scale \$WORK/sfm_txt $CAMERA_HEIGHT_M  # -> $SCALE, written as 4x4 matrix to \$WORK/scale.txt" >>"$COMMANDS"
printf '%s 0 0 0\n0 %s 0 0\n0 0 %s 0\n0 0 0 1\n' "$SCALE" "$SCALE" "$SCALE" >"$WORK/scale.txt"
run colmap model_transformer --input_path "$WORK/sfm/0" --output_path "$WORK/pseudo_gt" \
  --transform_path "$WORK/scale.txt"
colmap model_converter --input_path "$WORK/pseudo_gt" --output_path "$WORK/pseudo_gt_txt" \
  --output_type TXT >/dev/null 2>&1
colmap model_analyzer --path "$WORK/pseudo_gt" >"$WORK/pseudo_gt_stats.txt" 2>&1
N_REG=$(sed -n 's/.*Registered images: *//p' "$WORK/pseudo_gt_stats.txt")
[[ $N_REG == "$N_IMAGES" ]] || { echo "pseudo-GT registered $N_REG of $N_IMAGES images" >&2; exit 1; }
echo "   pseudo-GT: $N_REG images, scale $SCALE (road height quartiles $HEIGHT_Q1 / $HEIGHT_Q3 of the median)"

# 2. Shipped database: capped features, the same camera, sequential matching.
run colmap feature_extractor --database_path "$WORK/database.db" --image_path "$OUT/images" \
  "${CAMERA_ARGS[@]}" --SiftExtraction.use_gpu 0 --SiftExtraction.max_num_features "$MAX_FEATURES" \
  --SiftExtraction.max_num_orientations 1
run $TOOL cap_features "$WORK/database.db" "$MAX_FEATURES"
run $TOOL set_db_cameras "$WORK/pseudo_gt_txt" "$WORK/database.db"
run colmap sequential_matcher --database_path "$WORK/database.db" --SiftMatching.use_gpu 0 \
  --SequentialMatching.overlap 20

# 3. Map: triangulate with the pseudo-GT poses of the non-query frames.
run $TOOL map_input "$WORK/pseudo_gt_txt" "$WORK/database.db" "$WORK/map_in" "$QUERIES"
mkdir -p "$WORK/map"
run colmap point_triangulator --database_path "$WORK/database.db" --image_path "$OUT/images" \
  --input_path "$WORK/map_in" --output_path "$WORK/map" "${FIXED_CAMERA[@]}"
colmap model_analyzer --path "$WORK/map" >"$WORK/map_stats.txt" 2>&1
echo "colmap model_analyzer --path \$OUT/map" >>"$COMMANDS"
mkdir -p "$WORK/map_txt"
colmap model_converter --input_path "$WORK/map" --output_path "$WORK/map_txt" --output_type TXT >/dev/null 2>&1
$TOOL check_map "$WORK/map_txt" "$WORK/pseudo_gt_txt" "$WORK/database.db" "$QUERIES"
mkdir -p "$OUT/map"
cp "$WORK"/map/{cameras,images,points3D}.bin "$OUT/map/"

# 4. Queries and their pseudo-GT poses.
$TOOL queries "$WORK/pseudo_gt_txt" "$QUERIES" "$OUT"

# 5. Baseline: register the queries against the map, compare with the pseudo-GT.
mkdir -p "$WORK/registered" "$WORK/registered_txt"
run colmap image_registrator --database_path "$WORK/database.db" \
  --input_path "$WORK/map" --output_path "$WORK/registered"
colmap model_converter --input_path "$WORK/registered" --output_path "$WORK/registered_txt" \
  --output_type TXT >/dev/null 2>&1
$TOOL compare "$WORK/registered_txt" "$WORK/pseudo_gt_txt" "$QUERIES" >"$WORK/registration.txt"
cat "$WORK/registration.txt"

# 6. Ship the database without matches.
cp "$WORK/database.db" "$OUT/database.db"
$TOOL trim_db "$OUT/database.db"
DB_SUMMARY=$($TOOL db_summary "$OUT/database.db")
cp "$SRC/LICENSE" "$OUT/LICENSE.3dv_tutorial"
cat >"$OUT/LICENSE" <<'EOF'
The images in this folder (images/) are frames 000000-000159 of the left greyscale camera of
sequence 07 of the KITTI Vision Benchmark Suite's odometry data, as published in the GitHub
repository sunglok/3dv_tutorial (bin/data/07/image_0), converted from PNG to JPEG.

  Andreas Geiger, Philip Lenz and Raquel Urtasun, "Are we ready for Autonomous Driving? The KITTI
  Vision Benchmark Suite", Conference on Computer Vision and Pattern Recognition (CVPR), 2012.
  http://www.cvlibs.net/datasets/kitti/

The KITTI data are licensed under the Creative Commons Attribution-NonCommercial-ShareAlike 3.0
License (CC BY-NC-SA 3.0): https://creativecommons.org/licenses/by-nc-sa/3.0/
You may copy, redistribute and adapt them for non-commercial purposes, giving appropriate credit
(the citation above), indicating changes, and distributing adaptations under the same licence.

The files derived from the images here (database.db, map/, queries_with_intrinsics.txt,
queries_gt.txt) are shared under the same licence, CC BY-NC-SA 3.0.
EOF

# 7. README.
stat_line() { sed -n "s/.*$2: *//p" "$WORK/$1" | head -n 1; }
N_QUERIES=$(tr ',' '\n' <<<"$QUERIES" | grep -c .)
{
  cat <<EOF
# kitti-07 — a street driven by car (KITTI odometry sequence 07, 160 frames)

$N_IMAGES consecutive frames (10 Hz, 1226x370, greyscale, rectified) of the left camera of KITTI's
car driving through a residential street in Karlsruhe, Germany, with parked cars, houses and
turns. No poses ship with these frames: a COLMAP SfM reconstruction of all $N_IMAGES frames (built
from a richer feature set than the one shipped) is the **pseudo ground truth**. Queries:
$N_QUERIES frames, every 8th from frame 4, spread over the whole drive; map: the other
$((N_IMAGES - N_QUERIES)), triangulated with their pseudo-GT poses, so map and query poses are
consistent with each other.
Units: roughly metres. The SfM frame was scaled by $SCALE so that the camera sits
$CAMERA_HEIGHT_M m above the road (KITTI's mounting height), the road's height in the camera frame
taken as the median over $ROAD_OBSERVATIONS observations of road points (its quartiles are
$HEIGHT_Q1 and $HEIGHT_Q3 of the median). Orientation of the world frame is arbitrary (SfM).
Poses: cam_from_world (COLMAP convention, quaternion w x y z, translation).

## Files
| file | content |
| --- | --- |
| images/ | all $N_IMAGES frames (map + queries) as JPEG (quality 92) |
| database.db | COLMAP database: cameras, images, SIFT keypoints + descriptors of every image ($DB_SUMMARY; the $MAX_FEATURES largest-scale keypoints per image); matches and two_view_geometries removed |
| map/ | COLMAP binary model (cameras.bin, images.bin, points3D.bin) of the map images only; image ids, names and POINT2D_IDX refer to database.db keypoints |
| queries_with_intrinsics.txt | \`NAME MODEL WIDTH HEIGHT PARAMS...\` per query (Aachen format) |
| queries_gt.txt | \`NAME QW QX QY QZ TX TY TZ\` per query, pseudo ground truth cam_from_world |
| LICENSE | the images' licence (KITTI, CC BY-NC-SA 3.0) |
| LICENSE.3dv_tutorial | licence of the repository the frames were taken from |

Queries: $(tr ',' ' ' <<<"$QUERIES")

## Pseudo ground truth (SfM of all frames, not shipped)
- SIFT up to $PSEUDO_GT_FEATURES per frame, sequential guided matching (20 neighbours), COLMAP
  mapper defaults except the fixed camera (KITTI's calibration, P0 of calib.txt)
- registered images: $N_REG / $N_IMAGES, points: $(stat_line pseudo_gt_stats.txt Points),
  observations: $(stat_line pseudo_gt_stats.txt Observations),
  mean reprojection error: $(stat_line pseudo_gt_stats.txt 'Mean reprojection error')
- camera: $(cut -d' ' -f2- "$OUT/queries_with_intrinsics.txt" | head -n 1)
- sequence check: $($TOOL sequence_check "$WORK/pseudo_gt_txt")

## Map (\`colmap model_analyzer\`)
- cameras: $(stat_line map_stats.txt Cameras), registered images: $(stat_line map_stats.txt 'Registered images')
- points: $(stat_line map_stats.txt Points), observations: $(stat_line map_stats.txt Observations)
- mean track length: $(stat_line map_stats.txt 'Mean track length'), mean observations per image: $(stat_line map_stats.txt 'Mean observations per image')
- mean reprojection error: $(stat_line map_stats.txt 'Mean reprojection error')

## Baseline: \`colmap image_registrator\` on the queries vs pseudo ground truth
| query | position error (~m) | rotation error (deg) |
| --- | --- | --- |
EOF
  awk '{ if ($2 == "NOT_REGISTERED") print "| " $1 " | not registered | |";
         else printf "| %s | %.4f | %.3f |\n", $1, $2, $3 }' "$WORK/registration.txt"
  cat <<EOF

The queries took part in the pseudo-GT reconstruction (with other, richer features), so this
measures consistency with the SfM model, not absolute accuracy.

## How it was made
\`scripts/realdata/make_kitti07_set.sh \$SRC \$OUT\` (COLMAP 3.8, CPU, QT_QPA_PLATFORM=offscreen,
MAX_FEATURES=$MAX_FEATURES), which ran:
\`\`\`
EOF
  cat "$COMMANDS"
  cat <<EOF
\`\`\`

## Source and licence
Frames: GitHub \`sunglok/3dv_tutorial\` (commit cfbdfe377ae272614c5d0f434b0bf5cb4c7a80d3),
\`bin/data/07/image_0/000000.png\` .. \`000159.png\` and \`bin/data/07/calib.txt\`: the first 160
frames of sequence 07 of the KITTI odometry benchmark (A. Geiger, P. Lenz, R. Urtasun, "Are we
ready for Autonomous Driving? The KITTI Vision Benchmark Suite", CVPR 2012). The KITTI data are
published under **Creative Commons Attribution-NonCommercial-ShareAlike 3.0** (LICENSE): they may
be shared and adapted with attribution, for non-commercial purposes, under the same licence; the
derived database and models here are shared under the same terms. The tutorial repository's own
code is Beerware (LICENSE.3dv_tutorial).
EOF
} >"$OUT/README.md"
echo "== kitti-07 done: $(du -sh "$OUT" | cut -f1)"
