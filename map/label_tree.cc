#include "map/label_tree.h"

#include <faiss/Clustering.h>
#include <faiss/IndexFlat.h>
#include <omp.h>

#include <array>
#include <istream>
#include <limits>
#include <numeric>
#include <ostream>
#include <tuple>
#include <utility>

#include "util/binary_io.h"
#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr uint32_t kMagic = 0x54435348;  // "HSCT"
// Version 2 stores the labels only (the nodes follow from them); version 1 also stored the node
// arrays and centres, 13 times the bytes on an Aachen-sized map (docs/decisions.md).
constexpr uint32_t kVersion = 2;
constexpr uint32_t kFirstReadableVersion = 1;
constexpr int kMaxLevels = 255;  // node levels are stored as bytes
constexpr int kMaxBranching = 256;
// k-means trains on at most this many points per cluster (FAISS's default of 256 suits
// high-dimensional data). On the Aachen-sized synthetic city, 64 instead of 256 makes the level-1
// splits 2.8 times faster for a 2 % larger RMS distance of points to their centroid.
constexpr int kMaxTrainingPointsPerCluster = 64;
// Nodes with few points per cluster (most level-2 nodes of an Aachen-sized map hold about 2 per
// cluster) settle within a few iterations: there, 8 iterations reach the RMS distance of 20.
constexpr size_t kFewPointsPerCluster = 4;
constexpr int kFewPointsIterations = 8;

// base^exponent, saturating at the largest uint64_t.
uint64_t SaturatingPower(uint64_t base, int exponent) {
  uint64_t result = 1;
  for (int i = 0; i < exponent; ++i) {
    if (result > std::numeric_limits<uint64_t>::max() / base) {
      return std::numeric_limits<uint64_t>::max();
    }
    result *= base;
  }
  return result;
}

// Sets the OpenMP team size of the calling thread (OpenMP keeps it per thread) and restores it.
class ScopedOmpThreads {
 public:
  explicit ScopedOmpThreads(int num_threads) : previous_(omp_get_max_threads()) {
    omp_set_num_threads(num_threads);
  }
  ~ScopedOmpThreads() { omp_set_num_threads(previous_); }
  ScopedOmpThreads(const ScopedOmpThreads&) = delete;
  ScopedOmpThreads& operator=(const ScopedOmpThreads&) = delete;

 private:
  const int previous_;
};

float SquaredDistance(const float* a, const float* b) {
  const float dx = a[0] - b[0];
  const float dy = a[1] - b[1];
  const float dz = a[2] - b[2];
  return dx * dx + dy * dy + dz * dz;
}

// The nearest of k centroids (ties: the lowest index) of each of n points, all 3-D and
// row-major. Written for 3-D: the centroids are transposed so that the distance loop vectorizes.
void NearestCentroids(const float* x, size_t n, const float* centroids, size_t k, float* distances,
                      int64_t* labels) {
  std::vector<float> cx(k), cy(k), cz(k), distance(k);
  for (size_t c = 0; c < k; ++c) {
    cx[c] = centroids[3 * c];
    cy[c] = centroids[3 * c + 1];
    cz[c] = centroids[3 * c + 2];
  }
  for (size_t i = 0; i < n; ++i) {
    const float px = x[3 * i];
    const float py = x[3 * i + 1];
    const float pz = x[3 * i + 2];
    for (size_t c = 0; c < k; ++c) {
      const float dx = px - cx[c];
      const float dy = py - cy[c];
      const float dz = pz - cz[c];
      distance[c] = dx * dx + dy * dy + dz * dz;
    }
    // The minimum first, then its index, so that the minimum, too, vectorizes.
    float best_distance = distance[0];
    for (size_t c = 1; c < k; ++c) best_distance = std::min(best_distance, distance[c]);
    size_t best = 0;
    while (best + 1 < k && distance[best] != best_distance) ++best;
    distances[i] = best_distance;
    labels[i] = static_cast<int64_t>(best);
  }
}

// FAISS's k-means assigns points through an index. Its flat index goes through BLAS, which on
// 3-D points spends its time writing the n x k distance matrix; this one searches directly and
// makes the Aachen-sized tree about three times faster to build.
class Nearest3dIndex : public faiss::IndexFlatL2 {
 public:
  Nearest3dIndex() : faiss::IndexFlatL2(3) {}

  void search(idx_t n, const float* x, idx_t k, float* distances, idx_t* labels,
              const faiss::SearchParameters* params = nullptr) const override {
    if (k != 1) {
      faiss::IndexFlatL2::search(n, x, k, distances, labels, params);
      return;
    }
    NearestCentroids(x, static_cast<size_t>(n), get_xb(), static_cast<size_t>(ntotal), distances,
                     labels);
  }
};

// Moves points out of clusters holding more than `capacity` until none does, greedily by the
// smallest increase of squared distance: each round offers every point of an over-full cluster
// its cheapest cluster with room and accepts the offers in order of cost (ties by point), as long
// as the source is still over-full and the target still has room. A round that leaves a cluster
// over-full has filled at least one cluster, which never regains room, so there are at most
// k + 1 rounds.
void EnforceCapacity(const std::vector<float>& x, const std::vector<float>& centroids,
                     const std::vector<float>& nearest_distances, uint64_t capacity,
                     std::vector<int64_t>& assignment) {
  const size_t k = centroids.size() / 3;
  std::vector<uint64_t> sizes(k, 0);
  for (const int64_t cluster : assignment) ++sizes[cluster];
  struct Offer {
    float cost;
    uint32_t point;
    int64_t target;
  };
  std::vector<Offer> offers;
  for (;;) {
    offers.clear();
    for (size_t i = 0; i < assignment.size(); ++i) {
      const int64_t own = assignment[i];
      if (sizes[own] <= capacity) continue;
      // Clusters with room never become over-full, so a point here was never moved.
      const float own_distance = nearest_distances[i];
      int64_t best = -1;
      float best_distance = std::numeric_limits<float>::infinity();
      for (size_t c = 0; c < k; ++c) {
        if (sizes[c] >= capacity) continue;
        const float distance = SquaredDistance(&x[3 * i], &centroids[3 * c]);
        if (best < 0 || distance < best_distance) {
          best = static_cast<int64_t>(c);
          best_distance = distance;
        }
      }
      THROW_CHECK_GE(best, int64_t{0});  // the caller guarantees k * capacity >= number of points
      offers.push_back({best_distance - own_distance, static_cast<uint32_t>(i), best});
    }
    if (offers.empty()) return;
    std::sort(offers.begin(), offers.end(), [](const Offer& a, const Offer& b) {
      return std::tie(a.cost, a.point) < std::tie(b.cost, b.point);
    });
    for (const Offer& offer : offers) {
      int64_t& own = assignment[offer.point];
      if (sizes[own] <= capacity || sizes[offer.target] >= capacity) continue;
      --sizes[own];
      ++sizes[offer.target];
      own = offer.target;
    }
  }
}

// Computes the label paths of all points, node by node from the root.
class Labeler {
 public:
  Labeler(const std::vector<Eigen::Vector3d>& points, const LabelTreeOptions& options,
          std::vector<LabelTree::Label>& labels, ProgressBar& progress)
      : points_(points), options_(options), labels_(labels), progress_(progress) {}

  // Labels levels `level`.. of the points of one node (point indices in increasing order). The
  // subtrees of its children are labelled on up to num_threads threads; each node's k-means seed
  // depends on its path only, so the result does not depend on the thread count.
  void LabelNode(std::vector<uint32_t> members, int level, uint64_t node_key, int num_threads) {
    if (members.size() <= static_cast<size_t>(options_.branching)) {
      GiveEachPointItsOwnChild(members, level);
      return;
    }
    std::vector<std::vector<uint32_t>> children = Split(members, level, node_key, num_threads);
    members = {};
    for (size_t c = 0; c < children.size(); ++c) {
      for (const uint32_t point : children[c]) LabelOf(point, level) = static_cast<uint8_t>(c);
    }
    ParallelFor(children.size(), num_threads, [&](size_t begin, size_t end) {
      for (size_t c = begin; c < end; ++c) {
        LabelNode(std::move(children[c]), level + 1, ChildKey(node_key, c), 1);
      }
    });
  }

  static uint64_t ChildKey(uint64_t node_key, size_t child) {
    return MixBits(node_key * 257 + child + 1);
  }

 private:
  LabelTree::Label& LabelOf(uint32_t point, int level) {
    return labels_[static_cast<size_t>(point) * options_.levels + level];
  }

  void GiveEachPointItsOwnChild(const std::vector<uint32_t>& members, int level) {
    for (size_t rank = 0; rank < members.size(); ++rank) {
      LabelOf(members[rank], level) = static_cast<uint8_t>(rank);
      for (int deeper = level + 1; deeper < options_.levels; ++deeper) {
        LabelOf(members[rank], deeper) = 0;
      }
    }
    progress_.Advance(members.size());
  }

  // k-means of a node's points into `branching` clusters, made to respect the children's
  // capacity; returns the members of the non-empty clusters (in cluster order).
  std::vector<std::vector<uint32_t>> Split(const std::vector<uint32_t>& members, int level,
                                           uint64_t node_key, int num_threads) {
    // Parents' splits respected the capacities, so a node on level levels - 1 holds at most
    // `branching` points and is never split.
    THROW_CHECK_LT(level, options_.levels - 1);
    const uint64_t capacity = SaturatingPower(options_.branching, options_.levels - level - 1);
    const size_t n = members.size();
    const size_t k = options_.branching;

    // Relative to the node's mean, so that float32 keeps millimetres in kilometre-wide maps.
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const uint32_t point : members) mean += points_[point];
    mean /= static_cast<double>(n);
    std::vector<float> x(3 * n);
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector3d local = points_[members[i]] - mean;
      for (int d = 0; d < 3; ++d) x[3 * i + d] = static_cast<float>(local[d]);
    }

    faiss::ClusteringParameters parameters;
    parameters.niter = n < kFewPointsPerCluster * k
                           ? std::min(options_.kmeans_iterations, kFewPointsIterations)
                           : options_.kmeans_iterations;
    parameters.verbose = false;
    parameters.seed = static_cast<int>(Random(options_.seed, {node_key}).NextU64() & 0x7fffffff);
    // Few points per cluster are normal deeper in the tree; FAISS should not warn about them.
    parameters.min_points_per_centroid = 1;
    parameters.max_points_per_centroid = kMaxTrainingPointsPerCluster;
    faiss::Clustering clustering(3, static_cast<int>(k), parameters);
    Nearest3dIndex index;
    {
      // With the training sample capped, one split trains in milliseconds, and the barriers of an
      // OpenMP team cost more than they save (hundreds of milliseconds per tree on a loaded
      // machine); the threads work on whole subtrees and on the full assignment instead.
      const ScopedOmpThreads single_thread(1);
      clustering.train(static_cast<faiss::Index::idx_t>(n), x.data(), index);
    }
    const std::vector<float>& centroids = clustering.centroids;

    // FAISS may have trained on a sample, so every point is assigned here.
    std::vector<int64_t> assignment(n);
    std::vector<float> distances(n);
    ParallelFor(n, num_threads, [&](size_t begin, size_t end) {
      NearestCentroids(&x[3 * begin], end - begin, centroids.data(), k, &distances[begin],
                       &assignment[begin]);
    });
    EnforceCapacity(x, centroids, distances, capacity, assignment);

    std::vector<std::vector<uint32_t>> clusters(k);
    for (size_t i = 0; i < n; ++i) clusters[assignment[i]].push_back(members[i]);
    clusters.erase(std::remove_if(clusters.begin(), clusters.end(),
                                  [](const std::vector<uint32_t>& c) { return c.empty(); }),
                   clusters.end());
    return clusters;
  }

  const std::vector<Eigen::Vector3d>& points_;
  const LabelTreeOptions& options_;
  std::vector<LabelTree::Label>& labels_;
  ProgressBar& progress_;
};

}  // namespace

void LabelTreeOptions::Check() const {
  THROW_CHECK_MSG(levels >= 1 && levels <= kMaxLevels, "levels must be in [1, {}] (got {})",
                  kMaxLevels, levels);
  THROW_CHECK_MSG(branching >= 2 && branching <= kMaxBranching,
                  "branching must be in [2, {}] (got {})", kMaxBranching, branching);
  THROW_CHECK_MSG(kmeans_iterations >= 1, "kmeans_iterations must be >= 1 (got {})",
                  kmeans_iterations);
}

LabelTree LabelTree::Build(const std::vector<Eigen::Vector3d>& points,
                           const LabelTreeOptions& options) {
  options.Check();
  const uint64_t capacity = SaturatingPower(options.branching, options.levels);
  if (points.size() > capacity || points.size() > std::numeric_limits<uint32_t>::max()) {
    ThrowInvalidArgument(
        "label tree: {} points do not fit a tree of {} levels with branching {} (at most {})",
        points.size(), options.levels, options.branching, capacity);
  }
  for (size_t p = 0; p < points.size(); ++p) {
    if (!points[p].allFinite()) {
      ThrowInvalidArgument("label tree: point {} is not finite ({}, {}, {})", p, points[p].x(),
                           points[p].y(), points[p].z());
    }
  }

  LabelTree tree;
  tree.levels_ = options.levels;
  tree.branching_ = options.branching;
  tree.labels_.assign(points.size() * options.levels, 0);
  {
    ProgressBar progress(
        "label tree", points.size(),
        options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
    std::vector<uint32_t> all(points.size());
    std::iota(all.begin(), all.end(), 0u);
    Labeler(points, options, tree.labels_, progress)
        .LabelNode(std::move(all), 0, /*node_key=*/1, ResolveNumThreads(options.num_threads));
  }
  tree.BuildNodesFromLabels();
  tree.FindLevelsWithChoice();
  return tree;
}

void LabelTree::FindLevelsWithChoice() {
  level_has_choice_.assign(levels_, 0);
  for (size_t i = 0; i < labels_.size(); ++i) {
    if (labels_[i] != 0) level_has_choice_[i % levels_] = 1;
  }
}

std::vector<uint32_t> LabelTree::PointsInPathOrder() const {
  const size_t n = NumPoints();
  // Least-significant-digit radix sort, stable: the points of a node at any level are then one
  // contiguous range, and its children consecutive sub-ranges.
  std::vector<uint32_t> order(n);
  std::iota(order.begin(), order.end(), 0u);
  std::vector<uint32_t> sorted(n);
  for (int level = levels_ - 1; level >= 0; --level) {
    std::array<size_t, kMaxBranching + 1> start{};
    for (const uint32_t point : order) ++start[labels_[size_t{point} * levels_ + level] + 1];
    std::partial_sum(start.begin(), start.end(), start.begin());
    for (const uint32_t point : order) {
      sorted[start[labels_[size_t{point} * levels_ + level]]++] = point;
    }
    order.swap(sorted);
  }
  return order;
}

void LabelTree::BuildNodesFromLabels() {
  const size_t n = NumPoints();
  const auto label = [&](uint32_t point, int level) {
    return labels_[static_cast<size_t>(point) * levels_ + level];
  };
  for (uint32_t point = 0; point < n; ++point) {
    for (int level = 0; level < levels_; ++level) {
      if (label(point, level) >= branching_) {
        ThrowInvalidArgument("the labels of point {} hold {} at level {}, beyond branching {}",
                             point, label(point, level), level, branching_);
      }
    }
  }
  const std::vector<uint32_t> order = PointsInPathOrder();

  struct Range {
    size_t begin;
    size_t end;
  };
  const auto add_node = [&](int level, Range range) {
    node_level_.push_back(static_cast<uint8_t>(level));
    first_child_.push_back(0);
    num_children_.push_back(0);
    if (level == levels_) {
      if (range.end - range.begin != 1) {
        ThrowInvalidArgument("the labels of points {} and {} lead to the same leaf",
                             order[range.begin], order[range.begin + 1]);
      }
      leaf_point_.push_back(order[range.begin]);
    } else {
      leaf_point_.push_back(-1);
    }
  };

  node_level_.clear();
  first_child_.clear();
  num_children_.clear();
  leaf_point_.clear();
  std::vector<Range> current = {{0, n}};
  add_node(0, current.front());
  size_t current_first_node = 0;
  for (int level = 0; level < levels_; ++level) {
    std::vector<Range> next;
    const size_t next_first_node = current_first_node + current.size();
    for (size_t i = 0; i < current.size(); ++i) {
      const size_t node = current_first_node + i;
      first_child_[node] = static_cast<uint32_t>(next_first_node + next.size());
      for (size_t begin = current[i].begin; begin < current[i].end;) {
        const uint8_t child_label = label(order[begin], level);
        // Children are labelled 0 .. num_children - 1 without gaps.
        if (child_label != num_children_[node]) {
          ThrowInvalidArgument(
              "the labels of point {} skip a child: label {} at level {} where the parent has {} "
              "children before it",
              order[begin], child_label, level, num_children_[node]);
        }
        size_t end = begin + 1;
        while (end < current[i].end && label(order[end], level) == child_label) ++end;
        next.push_back({begin, end});
        ++num_children_[node];
        begin = end;
      }
    }
    for (const Range& range : next) add_node(level + 1, range);
    THROW_CHECK_LE(node_level_.size(), size_t{std::numeric_limits<uint32_t>::max()});
    current_first_node = next_first_node;
    current.swap(next);
  }
  nodes_per_level_.assign(levels_ + 1, 0);
  for (const uint8_t level : node_level_) ++nodes_per_level_[level];
}

std::vector<Eigen::Vector3d> LabelTree::NodeCenters(
    const std::vector<Eigen::Vector3d>& points) const {
  THROW_CHECK_EQ(points.size(), NumPoints());
  std::vector<Eigen::Vector3d> sums(NumNodes(), Eigen::Vector3d::Zero());
  std::vector<size_t> counts(NumNodes(), 0);
  for (uint32_t point = 0; point < points.size(); ++point) {
    for (int depth = 0; depth <= levels_; ++depth) {
      const auto node = static_cast<size_t>(NodeOfLabels(LabelsOfPoint(point), depth));
      sums[node] += points[point];
      ++counts[node];
    }
  }
  for (size_t node = 0; node < sums.size(); ++node) {
    if (counts[node] > 0) sums[node] /= static_cast<double>(counts[node]);
  }
  return sums;
}

int64_t LabelTree::NodeOfLabels(const Label* labels, int depth) const {
  THROW_CHECK_MSG(depth >= 0 && depth <= levels_, "depth {} outside [0, {}]", depth, levels_);
  if (node_level_.empty()) return -1;
  uint32_t node = 0;
  for (int level = 0; level < depth; ++level) {
    if (labels[level] >= num_children_[node]) return -1;
    node = first_child_[node] + labels[level];
  }
  return node;
}

int64_t LabelTree::PointOfLabels(const Label* labels) const {
  const int64_t node = NodeOfLabels(labels, levels_);
  return node < 0 ? -1 : leaf_point_[node];
}

int64_t LabelTree::PointOfLeaf(uint32_t node) const {
  THROW_CHECK_LT(size_t{node}, NumNodes());
  return leaf_point_[node];
}

void LabelTree::Write(std::ostream& stream) const {
  WriteBinary(stream, kMagic);
  WriteBinary(stream, kVersion);
  WriteBinary<uint32_t>(stream, levels_);
  WriteBinary<uint32_t>(stream, branching_);
  WriteBinary<uint64_t>(stream, NumPoints());
  WriteBinaryArray(stream, labels_.data(), labels_.size());
}

LabelTree LabelTree::Read(std::istream& stream, const std::string& source) {
  if (ReadBinary<uint32_t>(stream, source + ": magic") != kMagic) {
    ThrowInvalidArgument("{}: not an hscloc label tree (wrong magic)", source);
  }
  const auto version = ReadBinary<uint32_t>(stream, source + ": version");
  if (version < kFirstReadableVersion || version > kVersion) {
    ThrowInvalidArgument("{}: label tree version {} (this build reads versions {} to {})", source,
                         version, kFirstReadableVersion, kVersion);
  }
  LabelTree tree;
  const auto levels = ReadBinary<uint32_t>(stream, source + ": levels");
  const auto branching = ReadBinary<uint32_t>(stream, source + ": branching");
  if (levels < 1 || levels > kMaxLevels || branching < 2 || branching > kMaxBranching) {
    ThrowInvalidArgument("{}: impossible label tree shape ({} levels, branching {})", source,
                         levels, branching);
  }
  tree.levels_ = static_cast<int>(levels);
  tree.branching_ = static_cast<int>(branching);
  const auto num_points = ReadBinary<uint64_t>(stream, source + ": point count");
  if (num_points > SaturatingPower(branching, levels) ||
      num_points > std::numeric_limits<uint32_t>::max()) {
    ThrowInvalidArgument("{}: {} points cannot fit {} levels with branching {}", source, num_points,
                         levels, branching);
  }
  tree.labels_ = ReadBinaryVector<Label>(stream, num_points * levels, source + ": labels");
  if (version == 1) {
    // Version 1 stored the node arrays and centres after the labels; the labels alone define
    // the tree, so they are skipped (their presence is still required: a cut file is named).
    const auto num_nodes = ReadBinary<uint64_t>(stream, source + ": node count");
    if (num_nodes < 1 || num_nodes > 1 + num_points * levels) {
      ThrowInvalidArgument("{}: {} nodes for {} points and {} levels", source, num_nodes,
                           num_points, levels);
    }
    constexpr size_t kVersion1BytesPerNode = 1 + 4 + 4 + 8 + 3 * 4;
    ReadBinaryVector<uint8_t>(stream, kVersion1BytesPerNode * num_nodes, source + ": node arrays");
  }
  try {
    tree.BuildNodesFromLabels();
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", source, error.what());
  }
  tree.FindLevelsWithChoice();
  return tree;
}

bool LabelTree::operator==(const LabelTree& other) const {
  return levels_ == other.levels_ && branching_ == other.branching_ && labels_ == other.labels_ &&
         node_level_ == other.node_level_ && first_child_ == other.first_child_ &&
         num_children_ == other.num_children_ && leaf_point_ == other.leaf_point_;
}

}  // namespace hscloc
