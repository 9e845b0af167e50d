// Builds a map bundle from a COLMAP model and its features: the dense scene with every
// observation's descriptor, the hierarchical label tree over the 3D points, the per-image
// visibility lists, and the retrieval index over database images (VLAD computed here from the
// local features, or external global descriptors such as NetVLAD from an hloc .h5).
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "map/label_tree.h"
#include "retrieval/global_index.h"
#include "retrieval/vlad.h"
#include "scene/feature_io.h"

namespace hscloc {

struct MapBuildOptions {
  LabelTreeOptions label_tree;
  VladOptions vlad;
  GlobalIndexOptions global_index;
  JoinOptions join;
  // Database images whose features train the VLAD codebook, and whose VLAD vectors train its
  // whitening (read a batch at a time); all images are encoded. A whitening needs more images than
  // dimensions, and a city's database wants thousands of dimensions (VladOptions::whitened_dim).
  int max_vlad_training_images = 1000;
  int max_vlad_whitening_images = 4096;
  bool show_progress = true;
  void Check() const;
};

struct MapBuildInputs {
  std::filesystem::path model_dir;                       // COLMAP model (binary or text)
  std::filesystem::path features;                        // database.db or features.h5
  std::optional<std::filesystem::path> global_features;  // hloc global descriptors .h5
};

struct MapBuildSummary {
  size_t num_images = 0;
  size_t num_points = 0;
  size_t num_observations = 0;
  int descriptor_dim = 0;
  int global_descriptor_dim = 0;
  size_t num_tree_nodes = 0;
  double seconds_total = 0;
  double seconds_join = 0;
  double seconds_label_tree = 0;
  double seconds_retrieval = 0;
  double seconds_write = 0;
  uint64_t bundle_bytes = 0;
};

// Builds the map and writes it atomically to `bundle_dir` (replacing an existing bundle only once
// the new one is complete). Throws std::invalid_argument naming the bad input.
MapBuildSummary BuildMap(const MapBuildInputs& inputs, const MapBuildOptions& options,
                         const std::filesystem::path& bundle_dir);

}  // namespace hscloc
