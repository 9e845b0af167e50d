// Writes a synthetic city to a directory, streaming image by image so that memory stays bounded
// at any preset:
//   map/                         COLMAP binary model of the database images
//   features.h5                  hloc-style local features of database and query images
//   queries/day_time_queries_with_intrinsics.txt, queries/night_time_queries_with_intrinsics.txt
//                                Aachen format: NAME MODEL WIDTH HEIGHT PARAMS...
//   queries_gt.txt               NAME QW QX QY QZ TX TY TZ (cam_from_world)
//   queries/point3D_ids.txt      NAME ID... per query keypoint (-1: clutter or a point not in the
//   map) stats.json, README.md        counts and what each file is
#pragma once

#include <filesystem>
#include <string>

#include "scene/feature_io.h"
#include "synthetic/synthetic_city.h"

namespace hscloc {

struct SyntheticCityStats {
  size_t num_blocks = 0;
  size_t num_city_points = 0;  // all points of the city
  size_t num_map_points = 0;   // points with at least min_track_length database observations
  size_t num_database_images = 0;
  size_t num_database_observations = 0;
  size_t num_database_keypoints = 0;
  size_t num_day_queries = 0;
  size_t num_night_queries = 0;
  double mean_track_length = 0;
  double seconds = 0;

  std::string ToJson() const;
};

struct SyntheticCityWriteOptions {
  int num_threads = 0;  // <= 0: all cores
  bool show_progress = true;
  H5FloatPrecision precision = H5FloatPrecision::kFloat16;  // as hloc stores descriptors
  // Replace an existing output directory instead of refusing to.
  bool overwrite = false;
};

// Writes the city into `output_dir`. The files are written into a sibling temporary directory
// that is renamed into place at the end, so an interrupted run never leaves a half city behind.
// The same options and seed give byte-identical files.
SyntheticCityStats WriteSyntheticCity(const SyntheticCity& city,
                                      const std::filesystem::path& output_dir,
                                      const SyntheticCityWriteOptions& options = {});

}  // namespace hscloc
