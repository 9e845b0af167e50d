// Fixtures shared by the network's tests: a small random map (points, a 3-level label tree of
// branching 12, 9 images each seeing a random tenth of the points), random descriptors, and copies
// of a network as its archives store it.
#pragma once

#include <torch/torch.h>

#include <Eigen/Core>
#include <cmath>
#include <sstream>
#include <vector>

#include "map/label_tree.h"
#include "map/visibility.h"
#include "model/network.h"
#include "model/network_module.h"
#include "util/random.h"

namespace hscloc::testing_support {

// A random map: points in a box, a 3-level tree, images that each see a random subset of points.
struct RandomMap {
  LabelTree tree;
  Visibility visibility;
  NetworkShape shape;
};

// Points uniform in a 50 x 50 x 10 box.
inline std::vector<Eigen::Vector3d> RandomPoints(size_t count, Random& random) {
  std::vector<Eigen::Vector3d> points(count);
  for (Eigen::Vector3d& point : points) {
    point = {random.Uniform(0, 50), random.Uniform(0, 50), random.Uniform(0, 10)};
  }
  return points;
}

inline LabelTree RandomPointTree(const std::vector<Eigen::Vector3d>& points, int levels,
                                 int branching) {
  LabelTreeOptions tree_options;
  tree_options.levels = levels;
  tree_options.branching = branching;
  tree_options.show_progress = false;
  tree_options.num_threads = 1;
  return LabelTree::Build(points, tree_options);
}

inline RandomMap MakeRandomMap(uint64_t seed) {
  Random random(seed);
  const std::vector<Eigen::Vector3d> points = RandomPoints(600, random);
  RandomMap map;
  map.tree = RandomPointTree(points, 3, 12);
  const int num_images = 9;
  std::vector<uint32_t> image_indices;
  std::vector<uint32_t> point_indices;
  for (uint32_t image = 0; image < num_images; ++image) {
    for (uint32_t point = 0; point < points.size(); ++point) {
      if (random.Bernoulli(0.1)) {
        image_indices.push_back(image);
        point_indices.push_back(point);
      }
    }
  }
  map.visibility =
      Visibility::FromObservations(num_images, points.size(), image_indices, point_indices);
  map.shape = NetworkShape::ForTree(24, map.tree, num_images);
  return map;
}

// The four combinations of the two per-node options (the first is the paper's network), then
// pooled point rows, with a trunk per level and then shared, then pooled point rows at the
// descriptor's width with the descriptor shortcut.
inline std::vector<NetworkOptions> HeadVariants(NetworkOptions base, int descriptor_dim) {
  std::vector<NetworkOptions> variants;
  for (const bool node_conditioning : {false, true}) {
    for (const int node_output_dim : {0, 8}) {
      base.node_conditioning = node_conditioning;
      base.node_output_dim = node_output_dim;
      variants.push_back(base);
    }
  }
  base.pooled_point_rows = true;
  variants.push_back(base);
  base.shared_trunk = true;  // the large maps' default
  variants.push_back(base);
  base.shared_trunk = false;
  base.node_output_dim = descriptor_dim;
  base.descriptor_shortcut = true;
  variants.push_back(base);
  return variants;
}

// The shape with several rows per point (NetworkShape::point_row_offsets): 1, 2 or 3 by leaf rank.
inline NetworkShape WithPrototypeRows(NetworkShape shape) {
  const int64_t points = shape.nodes_per_depth.back();
  shape.point_row_offsets.assign(1, 0);
  for (int64_t rank = 0; rank < points; ++rank) {
    shape.point_row_offsets.push_back(shape.point_row_offsets.back() + 1 + rank % 3);
  }
  return shape;
}

// Beside the descriptor shortcut the projections start at zero, which would leave the layers
// before them out of a comparison of two inference paths: they get random weights here.
inline Network WithRandomProjections(Network network, uint64_t seed) {
  torch::NoGradGuard no_grad;
  torch::manual_seed(seed);
  for (auto& item : NetworkInternals::Module(network)->named_parameters()) {
    const std::string& name = item.key();
    if (name.size() >= 17 && name.compare(name.size() - 17, 17, "projection.weight") == 0) {
      item.value().normal_(0, 0.3);
    }
  }
  return network;
}

// 60 points in a 3-level tree of branching 12: its third level only ever has one child.
inline LabelTree SixtyPointTree() {
  Random random(21);
  std::vector<Eigen::Vector3d> points(60);
  for (Eigen::Vector3d& point : points) point = {random.Uniform(0, 9), random.Uniform(0, 9), 0};
  LabelTreeOptions tree_options;
  tree_options.levels = 3;
  tree_options.branching = 12;
  tree_options.show_progress = false;
  return LabelTree::Build(points, tree_options);
}

inline NetworkOptions SmallOptions() {
  NetworkOptions options;
  options.channels = 32;
  options.embedding_dim = 16;
  options.conditioned_layers = 2;
  options.trunk_channels = 40;
  return options;
}

inline DescriptorMatrix RandomDescriptors(int64_t rows, int64_t dim, uint64_t seed) {
  Random random(seed);
  DescriptorMatrix descriptors(rows, dim);
  for (int64_t i = 0; i < descriptors.size(); ++i) {
    descriptors.data()[i] = static_cast<float>(random.Normal());
  }
  return descriptors;
}

// A copy of the network through a full-precision archive (as checkpoints store it).
inline Network CopyAtFullPrecision(const Network& network) {
  torch::serialize::OutputArchive archive;
  NetworkInternals::SaveTo(network, archive, WeightStorage::kFloat32);
  std::stringstream stream;
  archive.save_to(stream);
  torch::serialize::InputArchive input;
  input.load_from(stream);
  return NetworkInternals::LoadFrom(input, "checkpoint", ComputeDevice::kCpu);
}

// The network with every matrix rounded to 8-bit rows and back: what a bundle keeps. With several
// rows per point, each point row is rounded with its bias plus log of its point's rows.
inline Network AsStoredInABundle(const Network& network) {
  Network rounded = CopyAtFullPrecision(network);
  torch::NoGradGuard no_grad;
  const std::vector<int64_t>& offsets = network.shape().point_row_offsets;
  torch::Tensor log_rows = torch::zeros({offsets.empty() ? 0 : offsets.back()});
  for (size_t rank = 0; rank + 1 < offsets.size(); ++rank) {
    log_rows.narrow(0, offsets[rank], offsets[rank + 1] - offsets[rank])
        .fill_(std::log(static_cast<double>(offsets[rank + 1] - offsets[rank])));
  }
  for (auto& item : NetworkInternals::Module(rounded)->named_parameters()) {
    if (item.value().dim() != 2) continue;
    const bool shifted = item.key() == "point_rows" && !offsets.empty();
    torch::Tensor rows = item.value().clone();
    if (shifted) rows.select(1, rows.size(1) - 1).add_(log_rows);
    rows = DequantizeRows(QuantizeRows(rows));
    if (shifted) rows.select(1, rows.size(1) - 1).sub_(log_rows);
    item.value().copy_(rows);
  }
  return rounded;
}

}  // namespace hscloc::testing_support
