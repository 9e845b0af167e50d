// The hierarchical k-means tree over the map's 3D points whose label paths the network predicts
// (Li et al., "Hierarchical Scene Coordinate Classification and Regression for Visual
// Localization", CVPR 2020, Sec. 3.1).
//
// Every point gets a label path (l_1, ..., l_levels), each label the index of a child among its
// parent's children (0 .. branching-1), and every leaf holds exactly one point, so a full label
// path decodes to one point. A cluster with no more points than the branching factor gives each
// point its own child (in point index order); deeper levels then carry label 0. To guarantee that,
// each k-means split (FAISS) is capacity-constrained: a child may hold at most
// branching^(levels below it) points, and points of over-full clusters move to the clusters with
// room that increase their squared distance least. Empty clusters are dropped, so the children of
// a node are labelled 0 .. num_children - 1 without gaps.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <iosfwd>
#include <string>
#include <vector>

namespace hscloc {

struct LabelTreeOptions {
  int levels = 4;
  int branching = 100;         // at most 256: labels are stored as bytes
  int kmeans_iterations = 20;  // per split; splits with < 4 points per cluster run at most 8
  uint64_t seed = 0;           // the tree depends on the seed, not on num_threads
  int num_threads = 0;         // <= 0: all cores
  bool show_progress = true;
  void Check() const;
};

class LabelTree {
 public:
  using Label = uint8_t;

  // Builds the tree over points (dense point index -> position). Throws when the points cannot
  // fit (more than branching^levels points) or are not finite.
  static LabelTree Build(const std::vector<Eigen::Vector3d>& points,
                         const LabelTreeOptions& options);

  int levels() const { return levels_; }
  int branching() const { return branching_; }
  size_t NumPoints() const { return labels_.size() / std::max(levels_, 1); }

  // The label path of a point: `levels` labels.
  const Label* LabelsOfPoint(uint32_t point_index) const {
    return labels_.data() + static_cast<size_t>(point_index) * levels_;
  }
  // The point a full label path leads to, or -1 when no point is there (a path through an empty
  // or missing child).
  int64_t PointOfLabels(const Label* labels) const;

  // Nodes: level 0 is the root; a node's children are contiguous, first_child(node) ..
  // first_child(node) + num_children(node) - 1, in label order. A leaf (level == levels) holds a
  // point.
  size_t NumNodes() const { return node_level_.size(); }
  int NodeLevel(uint32_t node) const { return node_level_[node]; }
  // How many nodes each level holds, the root's first: levels() + 1 counts.
  const std::vector<int64_t>& NodesPerLevel() const { return nodes_per_level_; }
  uint32_t FirstChild(uint32_t node) const { return first_child_[node]; }
  uint32_t NumChildren(uint32_t node) const { return num_children_[node]; }
  // The point of a leaf node; -1 for inner nodes.
  int64_t PointOfLeaf(uint32_t node) const;
  // Whether some node offers a choice at `level` (0-based: the level of label `level`), i.e. has
  // more than one child there. Where none does, every label of that level is 0 and a classifier
  // has nothing to decide (the last level of a map with fewer than branching^(levels-1) points).
  bool LevelHasChoice(int level) const { return level_has_choice_.at(level) != 0; }
  // The cluster centre of every node (the mean of the points below it; zero for a childless
  // root), given the points the tree was built over (dense point index -> position).
  std::vector<Eigen::Vector3d> NodeCenters(const std::vector<Eigen::Vector3d>& points) const;
  // The node a label prefix leads to (`depth` labels, 0 .. levels; other depths throw), or -1.
  int64_t NodeOfLabels(const Label* labels, int depth) const;

  // Little-endian: magic "HSCT", version, shape, then the labels; the nodes are derived from the
  // labels when read.
  void Write(std::ostream& stream) const;
  // Throws std::invalid_argument naming `source` when the data is truncated or inconsistent.
  static LabelTree Read(std::istream& stream, const std::string& source);

  bool operator==(const LabelTree& other) const;

 private:
  int levels_ = 0;
  int branching_ = 0;
  std::vector<Label> labels_;  // point-major: labels_[point * levels + level]
  std::vector<uint8_t> node_level_;
  std::vector<int64_t> nodes_per_level_;
  std::vector<uint32_t> first_child_;
  std::vector<uint32_t> num_children_;
  std::vector<int64_t> leaf_point_;        // per node; -1 for inner nodes
  std::vector<uint8_t> level_has_choice_;  // per level, derived from labels_

  // Derives the nodes (breadth-first, children in label order) from labels_. Throws
  // std::invalid_argument when the labels are not a tree's: a label beyond the branching, a
  // child label with a gap before it, two points on one leaf.
  void BuildNodesFromLabels();
  // Point indices sorted by label path.
  std::vector<uint32_t> PointsInPathOrder() const;
  // Derives level_has_choice_ from labels_: labels are dense, so a level offers a choice exactly
  // where some point's label there is not 0.
  void FindLevelsWithChoice();
};

}  // namespace hscloc
