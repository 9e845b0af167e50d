#include "map/label_tree.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "synthetic/synthetic_city.h"
#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

LabelTreeOptions QuietOptions(int levels, int branching, uint64_t seed = 0) {
  LabelTreeOptions options;
  options.levels = levels;
  options.branching = branching;
  options.seed = seed;
  options.show_progress = false;
  return options;
}

std::vector<Eigen::Vector3d> RandomPoints(size_t count, uint64_t seed) {
  Random random(seed);
  std::vector<Eigen::Vector3d> points(count);
  for (Eigen::Vector3d& point : points) {
    point =
        Eigen::Vector3d(random.Uniform(-100, 100), random.Uniform(-50, 50), random.Uniform(0, 20));
  }
  return points;
}

// Checks every structural promise of the header against the points the tree was built on.
void ExpectValidTree(const LabelTree& tree, const std::vector<Eigen::Vector3d>& points,
                     const LabelTreeOptions& options) {
  ASSERT_EQ(tree.levels(), options.levels);
  ASSERT_EQ(tree.branching(), options.branching);
  ASSERT_EQ(tree.NumPoints(), points.size());
  ASSERT_GE(tree.NumNodes(), 1u);
  EXPECT_EQ(tree.NodeLevel(0), 0);

  // Every point's path is valid and ends in a leaf holding that point; leaves are points.
  std::vector<int> points_at_leaf(tree.NumNodes(), 0);
  std::vector<size_t> count(tree.NumNodes(), 0);
  for (uint32_t p = 0; p < points.size(); ++p) {
    const LabelTree::Label* labels = tree.LabelsOfPoint(p);
    for (int level = 0; level < tree.levels(); ++level) {
      ASSERT_LT(labels[level], options.branching) << "point " << p;
    }
    ASSERT_EQ(tree.PointOfLabels(labels), p);
    for (int depth = 0; depth <= tree.levels(); ++depth) {
      const int64_t node = tree.NodeOfLabels(labels, depth);
      ASSERT_GE(node, 0);
      ASSERT_EQ(tree.NodeLevel(node), depth);
      ++count[node];
    }
    const int64_t leaf = tree.NodeOfLabels(labels, tree.levels());
    ++points_at_leaf[leaf];
    EXPECT_EQ(tree.PointOfLeaf(leaf), p);
  }

  size_t num_leaves = 0;
  std::vector<int64_t> nodes_per_level(tree.levels() + 1, 0);
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) {
    ++nodes_per_level[tree.NodeLevel(node)];
    ASSERT_LE(tree.NumChildren(node), static_cast<uint32_t>(options.branching));
    for (uint32_t c = 0; c < tree.NumChildren(node); ++c) {
      ASSERT_EQ(tree.NodeLevel(tree.FirstChild(node) + c), tree.NodeLevel(node) + 1);
    }
    if (tree.NodeLevel(node) == tree.levels()) {
      ++num_leaves;
      EXPECT_EQ(points_at_leaf[node], 1) << "leaf " << node;
      EXPECT_EQ(tree.NumChildren(node), 0u);
    } else {
      EXPECT_EQ(tree.PointOfLeaf(node), -1);
      if (!points.empty()) {
        EXPECT_GE(tree.NumChildren(node), 1u) << "empty inner node " << node;
      }
    }
    // Every node is on some point's path.
    if (node > 0 || !points.empty()) {
      ASSERT_GT(count[node], 0u) << "node " << node;
    }
  }
  EXPECT_EQ(num_leaves, points.size());
  EXPECT_EQ(tree.NodesPerLevel(), nodes_per_level);
}

// A label path that leaves an inner node through a child it does not have.
std::vector<LabelTree::Label> PathThroughMissingChild(const LabelTree& tree) {
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) {
    if (tree.NodeLevel(node) == tree.levels() ||
        tree.NumChildren(node) >= static_cast<uint32_t>(tree.branching())) {
      continue;
    }
    // Find the path of this node through any point below it.
    for (uint32_t p = 0; p < tree.NumPoints(); ++p) {
      const LabelTree::Label* labels = tree.LabelsOfPoint(p);
      if (tree.NodeOfLabels(labels, tree.NodeLevel(node)) != node) continue;
      std::vector<LabelTree::Label> path(labels, labels + tree.levels());
      path[tree.NodeLevel(node)] = static_cast<LabelTree::Label>(tree.NumChildren(node));
      return path;
    }
  }
  return {};
}

TEST(LabelTreeOptions, CheckNamesTheField) {
  EXPECT_THAT(testing::InvalidArgumentMessage([] { QuietOptions(0, 10).Check(); }),
              HasSubstr("levels"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { QuietOptions(3, 1).Check(); }),
              HasSubstr("branching"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { QuietOptions(3, 257).Check(); }),
              HasSubstr("branching"));
  LabelTreeOptions options = QuietOptions(3, 10);
  options.kmeans_iterations = 0;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { options.Check(); }),
              HasSubstr("kmeans_iterations"));
  EXPECT_NO_THROW(QuietOptions(4, 256).Check());
}

class LabelTreeRandomPoints : public ::testing::TestWithParam<int> {};

TEST_P(LabelTreeRandomPoints, EveryPointHasItsOwnLeaf) {
  const int branching = GetParam();
  const LabelTreeOptions options = QuietOptions(3, branching, /*seed=*/branching);
  // Most of the capacity, so that the capacity limits of the children bind.
  const size_t count = branching * branching * branching * 7 / 10;
  const std::vector<Eigen::Vector3d> points = RandomPoints(count, branching);
  const LabelTree tree = LabelTree::Build(points, options);
  ExpectValidTree(tree, points, options);

  const std::vector<LabelTree::Label> missing = PathThroughMissingChild(tree);
  ASSERT_FALSE(missing.empty());
  EXPECT_EQ(tree.PointOfLabels(missing.data()), -1);
}

INSTANTIATE_TEST_SUITE_P(Branching, LabelTreeRandomPoints, ::testing::Values(10, 17, 40));

TEST(LabelTree, SmallCityTreeIsValidAndSpatiallyCompact) {
  const SyntheticCity city(SyntheticCityOptions::Preset("small"));
  const std::vector<Eigen::Vector3d>& points = city.points();
  LabelTreeOptions options;
  options.show_progress = false;
  const LabelTree tree = LabelTree::Build(points, options);
  ExpectValidTree(tree, points, options);

  std::vector<size_t> nodes_per_level(tree.levels() + 1, 0);
  std::vector<size_t> inner_per_level(tree.levels() + 1, 0);
  std::vector<size_t> children_per_level(tree.levels() + 1, 0);
  std::vector<uint32_t> max_children_per_level(tree.levels() + 1, 0);
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) {
    const int level = tree.NodeLevel(node);
    ++nodes_per_level[level];
    if (level == tree.levels()) continue;
    ++inner_per_level[level];
    children_per_level[level] += tree.NumChildren(node);
    max_children_per_level[level] = std::max(max_children_per_level[level], tree.NumChildren(node));
  }
  // Points per level-1 cluster and spatial compactness: mean distance of the points to the centre
  // of their node on each level.
  Eigen::Vector3d city_mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& point : points) city_mean += point;
  city_mean /= static_cast<double>(points.size());
  double spread = 0;
  for (const Eigen::Vector3d& point : points) spread += (point - city_mean).norm();
  spread /= static_cast<double>(points.size());
  const std::vector<Eigen::Vector3d> centers = tree.NodeCenters(points);
  std::vector<double> mean_distance(tree.levels() + 1, 0.0);
  std::vector<size_t> points_per_level1(tree.NumNodes(), 0);
  for (uint32_t p = 0; p < points.size(); ++p) {
    for (int depth = 1; depth <= tree.levels(); ++depth) {
      const int64_t node = tree.NodeOfLabels(tree.LabelsOfPoint(p), depth);
      mean_distance[depth] += (points[p] - centers[node]).norm();
      if (depth == 1) ++points_per_level1[node];
    }
  }
  size_t min_level1 = points.size();
  size_t max_level1 = 0;
  for (uint32_t c = 0; c < tree.NumChildren(0); ++c) {
    min_level1 = std::min(min_level1, points_per_level1[tree.FirstChild(0) + c]);
    max_level1 = std::max(max_level1, points_per_level1[tree.FirstChild(0) + c]);
  }

  std::cout << "small city: " << points.size() << " points, spread (mean distance to the mean) "
            << spread << " m, " << tree.NumNodes() << " nodes, depth " << tree.levels()
            << ", one point per leaf\n";
  for (int level = 0; level <= tree.levels(); ++level) {
    mean_distance[level] /= static_cast<double>(points.size());
    std::cout << "  level " << level << ": " << nodes_per_level[level] << " nodes";
    if (inner_per_level[level] > 0) {
      std::cout << ", children mean "
                << static_cast<double>(children_per_level[level]) / inner_per_level[level]
                << " max " << max_children_per_level[level];
    }
    if (level > 0) std::cout << ", mean distance to centre " << mean_distance[level] << " m";
    std::cout << "\n";
    ::testing::Test::RecordProperty("nodes_level_" + std::to_string(level),
                                    std::to_string(nodes_per_level[level]));
  }
  std::cout << "  points per level-1 node: min " << min_level1 << " max " << max_level1 << "\n";

  EXPECT_GT(points.size(), 10000u);
  EXPECT_EQ(nodes_per_level[0], 1u);
  EXPECT_EQ(nodes_per_level[1], static_cast<size_t>(options.branching));
  EXPECT_EQ(nodes_per_level[tree.levels()], points.size());
  EXPECT_LE(max_level1, 10 * points.size() / options.branching);
  // k-means clusters of a city are compact; a random partition would keep the full spread.
  EXPECT_LT(mean_distance[1], 0.25 * spread);
  EXPECT_LT(mean_distance[2], 0.5 * mean_distance[1]);
}

TEST(LabelTree, ExactlyFullTreeUsesEveryChild) {
  const LabelTreeOptions options = QuietOptions(3, 10, 7);
  const std::vector<Eigen::Vector3d> points = RandomPoints(1000, 7);
  const LabelTree tree = LabelTree::Build(points, options);
  ExpectValidTree(tree, points, options);
  EXPECT_EQ(tree.NumNodes(), 1u + 10 + 100 + 1000);
  for (uint32_t node = 0; node < tree.NumNodes(); ++node) {
    if (tree.NodeLevel(node) < tree.levels()) {
      EXPECT_EQ(tree.NumChildren(node), 10u);
    }
  }
}

TEST(LabelTree, LevelsBelowSingletonClustersOfferNoChoice) {
  // 60 points, branching 12: level 1 splits them into clusters of about 5, level 2 into single
  // points, so every level-3 parent has exactly one child.
  const LabelTreeOptions options = QuietOptions(3, 12, 3);
  const std::vector<Eigen::Vector3d> points = RandomPoints(60, 3);
  const LabelTree tree = LabelTree::Build(points, options);
  EXPECT_TRUE(tree.LevelHasChoice(0));
  EXPECT_TRUE(tree.LevelHasChoice(1));
  EXPECT_FALSE(tree.LevelHasChoice(2));
  for (uint32_t point = 0; point < points.size(); ++point) {
    EXPECT_EQ(tree.LabelsOfPoint(point)[2], 0);
  }
  std::stringstream stream;
  tree.Write(stream);
  const LabelTree read = LabelTree::Read(stream, "tree.bin");
  EXPECT_FALSE(read.LevelHasChoice(2));
  EXPECT_TRUE(read.LevelHasChoice(1));

  // A full tree offers a choice on every level.
  const LabelTree full = LabelTree::Build(RandomPoints(1000, 7), QuietOptions(3, 10, 7));
  for (int level = 0; level < 3; ++level) EXPECT_TRUE(full.LevelHasChoice(level)) << level;
}

TEST(LabelTree, TooManyPointsThrow) {
  const std::vector<Eigen::Vector3d> points = RandomPoints(1001, 7);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Build(points, QuietOptions(3, 10)); }),
      HasSubstr("1001 points"));
}

TEST(LabelTree, NonFinitePointsThrowNamingThePoint) {
  std::vector<Eigen::Vector3d> points = RandomPoints(50, 3);
  points[17].y() = std::nan("");
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Build(points, QuietOptions(3, 10)); }),
      HasSubstr("point 17"));
  points[17].y() = 0;
  points[23].z() = std::numeric_limits<double>::infinity();
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Build(points, QuietOptions(3, 10)); }),
      HasSubstr("point 23"));
}

TEST(LabelTree, OnePointAndNoPoints) {
  const LabelTreeOptions options = QuietOptions(4, 100);
  const std::vector<Eigen::Vector3d> one = {Eigen::Vector3d(1e6, 2e6, 30)};
  const LabelTree tree = LabelTree::Build(one, options);
  ExpectValidTree(tree, one, options);
  EXPECT_EQ(tree.NumNodes(), 5u);
  const std::vector<LabelTree::Label> zeros(4, 0);
  EXPECT_EQ(tree.PointOfLabels(zeros.data()), 0);
  const std::vector<LabelTree::Label> other = {0, 0, 1, 0};
  EXPECT_EQ(tree.PointOfLabels(other.data()), -1);
  EXPECT_EQ(tree.NodeOfLabels(other.data(), 3), -1);

  const LabelTree empty = LabelTree::Build({}, options);
  ExpectValidTree(empty, {}, options);
  EXPECT_EQ(empty.NumNodes(), 1u);
  EXPECT_EQ(empty.PointOfLabels(zeros.data()), -1);
}

TEST(LabelTree, DuplicatePoints) {
  const LabelTreeOptions options = QuietOptions(3, 10, 5);
  std::vector<Eigen::Vector3d> points;
  for (const Eigen::Vector3d& point : RandomPoints(300, 5)) points.insert(points.end(), 3, point);
  const LabelTree tree = LabelTree::Build(points, options);
  ExpectValidTree(tree, points, options);
}

TEST(LabelTree, IdenticalPointsFillTheTree) {
  const LabelTreeOptions options = QuietOptions(3, 10, 5);
  const std::vector<Eigen::Vector3d> points(1000, Eigen::Vector3d(3, -4, 5));
  const LabelTree tree = LabelTree::Build(points, options);
  ExpectValidTree(tree, points, options);
  EXPECT_EQ(tree.NumNodes(), 1u + 10 + 100 + 1000);
}

TEST(LabelTree, DeterministicForASeedWhateverTheThreadCount) {
  const std::vector<Eigen::Vector3d> points = RandomPoints(20000, 11);
  LabelTreeOptions options = QuietOptions(3, 40, 3);
  options.num_threads = 1;
  const LabelTree single = LabelTree::Build(points, options);
  options.num_threads = 2;
  const LabelTree first = LabelTree::Build(points, options);
  const LabelTree second = LabelTree::Build(points, options);
  options.num_threads = 3;
  const LabelTree third = LabelTree::Build(points, options);
  EXPECT_TRUE(first == second);
  EXPECT_TRUE(single == first);
  EXPECT_TRUE(third == first);
  ExpectValidTree(first, points, options);

  // The seed matters, so the equalities above are not trivially true.
  options.seed = 4;
  EXPECT_FALSE(LabelTree::Build(points, options) == first);
}

TEST(LabelTree, WriteReadRoundTrip) {
  const LabelTreeOptions options = QuietOptions(3, 20, 2);
  const std::vector<Eigen::Vector3d> points = RandomPoints(3000, 2);
  const LabelTree tree = LabelTree::Build(points, options);
  std::stringstream stream;
  tree.Write(stream);
  const LabelTree read = LabelTree::Read(stream, "tree.bin");
  EXPECT_TRUE(read == tree);
  ExpectValidTree(read, points, options);

  std::stringstream empty_stream;
  LabelTree::Build({}, options).Write(empty_stream);
  EXPECT_TRUE(LabelTree::Read(empty_stream, "empty.bin") == LabelTree::Build({}, options));
}

TEST(LabelTree, TruncatedOrCorruptDataThrowsNamingTheSource) {
  const LabelTree tree = LabelTree::Build(RandomPoints(500, 9), QuietOptions(3, 10, 9));
  std::stringstream stream;
  tree.Write(stream);
  const std::string bytes = stream.str();
  for (const size_t length :
       {size_t{0}, size_t{3}, size_t{10}, size_t{30}, bytes.size() / 2, bytes.size() - 1}) {
    std::istringstream truncated(bytes.substr(0, length));
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { LabelTree::Read(truncated, "tree.bin"); }),
                HasSubstr("tree.bin"))
        << "truncated to " << length << " bytes";
  }

  // Labels start after magic, version, levels, branching and the point count.
  constexpr size_t kFirstLabel = 24;
  std::string bad_label = bytes;
  bad_label[kFirstLabel] = static_cast<char>(200);
  std::istringstream bad_label_stream(bad_label);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Read(bad_label_stream, "tree.bin"); }),
      HasSubstr("tree.bin: the labels of point 0"));

  std::string bad_magic = bytes;
  bad_magic[0] = 'X';
  std::istringstream bad_magic_stream(bad_magic);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Read(bad_magic_stream, "tree.bin"); }),
      HasSubstr("tree.bin: not an hscloc label tree"));

  // Two points on one leaf: a point whose last label is its parent's last child takes label 0.
  std::string same_leaf = bytes;
  for (uint32_t p = 0; p < 500; ++p) {
    const LabelTree::Label* labels = tree.LabelsOfPoint(p);
    const int64_t parent = tree.NodeOfLabels(labels, 2);
    if (tree.NumChildren(parent) > 1 && labels[2] == tree.NumChildren(parent) - 1) {
      same_leaf[kFirstLabel + 3 * p + 2] = 0;
      break;
    }
  }
  std::istringstream same_leaf_stream(same_leaf);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { LabelTree::Read(same_leaf_stream, "tree.bin"); }),
      HasSubstr("lead to the same leaf"));

  // A root child label with a gap before it: every point's first label becomes 1.
  std::string gap = bytes;
  for (size_t point = 0; point < 500; ++point) gap[kFirstLabel + 3 * point] = 1;
  std::istringstream gap_stream(gap);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { LabelTree::Read(gap_stream, "tree.bin"); }),
              HasSubstr("tree.bin: the labels of point"));
}

// The root's centre is the mean of all points, a leaf's is its point, and an inner node's is the
// mean of its children's centres weighted by their point counts.
TEST(LabelTree, NodeCentersAreTheMeansOfTheirPoints) {
  const std::vector<Eigen::Vector3d> points = RandomPoints(500, 3);
  const LabelTree tree = LabelTree::Build(points, QuietOptions(3, 8, 3));
  const std::vector<Eigen::Vector3d> centers = tree.NodeCenters(points);
  ASSERT_EQ(centers.size(), tree.NumNodes());
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& point : points) mean += point;
  EXPECT_LT((centers[0] - mean / 500.0).norm(), 1e-9);

  std::vector<size_t> count(tree.NumNodes(), 0);
  for (uint32_t node = static_cast<uint32_t>(tree.NumNodes()); node-- > 0;) {
    if (tree.NodeLevel(node) == tree.levels()) {
      EXPECT_EQ(centers[node], points[tree.PointOfLeaf(node)]);
      count[node] = 1;
      continue;
    }
    Eigen::Vector3d weighted = Eigen::Vector3d::Zero();
    for (uint32_t c = 0; c < tree.NumChildren(node); ++c) {
      const uint32_t child = tree.FirstChild(node) + c;
      weighted += static_cast<double>(count[child]) * centers[child];
      count[node] += count[child];
    }
    EXPECT_LT((centers[node] - weighted / static_cast<double>(count[node])).norm(), 1e-9)
        << "node " << node;
  }
  EXPECT_EQ(count[0], points.size());
}

// Version 1 files (labels, then node arrays and centres) still read, to the same tree.
TEST(LabelTree, ReadsVersionOneFiles) {
  const LabelTree tree = LabelTree::Build(RandomPoints(800, 5), QuietOptions(3, 10, 5));
  std::stringstream stream;
  tree.Write(stream);
  std::string bytes = stream.str();
  bytes[4] = 1;  // the version, after the magic
  constexpr size_t kVersion1BytesPerNode = 1 + 4 + 4 + 8 + 3 * 4;
  const uint64_t num_nodes = tree.NumNodes();
  bytes.append(reinterpret_cast<const char*>(&num_nodes), sizeof(num_nodes));
  bytes.append(kVersion1BytesPerNode * num_nodes, '\0');
  std::istringstream version1(bytes);
  EXPECT_TRUE(LabelTree::Read(version1, "v1.bin") == tree);

  std::istringstream cut(bytes.substr(0, bytes.size() - 1));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { LabelTree::Read(cut, "v1.bin"); }),
              HasSubstr("v1.bin: node arrays"));
}

// An Aachen-sized tree (1.5 M points, the default 4 levels and branching 100), for measuring the
// build time by hand: --gtest_also_run_disabled_tests --gtest_filter='*AachenScale*'.
TEST(LabelTree, DISABLED_AachenScaleBuild) {
  const auto generate_start = std::chrono::steady_clock::now();
  const std::vector<Eigen::Vector3d> points =
      SyntheticCity(SyntheticCityOptions::Preset("aachen")).points();
  const auto build_start = std::chrono::steady_clock::now();
  LabelTreeOptions options;
  const LabelTree tree = LabelTree::Build(points, options);
  const auto end = std::chrono::steady_clock::now();
  std::cout << points.size() << " points (generated in "
            << std::chrono::duration<double>(build_start - generate_start).count()
            << " s): tree of " << tree.NumNodes() << " nodes built in "
            << std::chrono::duration<double>(end - build_start).count() << " s\n";
  const std::vector<Eigen::Vector3d> centers = tree.NodeCenters(points);
  std::vector<double> mean_distance(tree.levels() + 1, 0.0);
  for (uint32_t p = 0; p < points.size(); ++p) {
    ASSERT_EQ(tree.PointOfLabels(tree.LabelsOfPoint(p)), p);
    for (int depth = 1; depth < tree.levels(); ++depth) {
      const int64_t node = tree.NodeOfLabels(tree.LabelsOfPoint(p), depth);
      mean_distance[depth] += (points[p] - centers[node]).norm();
    }
  }
  for (int depth = 1; depth < tree.levels(); ++depth) {
    std::cout << "  level " << depth << ": mean distance to centre "
              << mean_distance[depth] / static_cast<double>(points.size()) << " m\n";
  }
}

}  // namespace
}  // namespace hscloc
