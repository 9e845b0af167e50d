// The explicit-matching baseline: mutual nearest neighbours with Lowe's ratio test between a
// query's descriptors and the observations of one database image (Lowe, IJCV 2004). The same
// matching serves other rows that stand for points (localization/point_row_matches.h).
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "scene/features.h"
#include "scene/scene.h"

namespace hscloc {

// Keypoint -> point matches against one candidate image: query keypoint rows and the dense point
// indices (into Scene::points) they matched, pairwise.
struct CandidateMatches {
  std::vector<int> keypoints;
  std::vector<uint32_t> point_indices;
  // The network's confidence in each match (PointPredictions::confidences); empty for matchers
  // without one.
  std::vector<float> confidences;

  size_t size() const { return keypoints.size(); }
};

// The matches at `chosen` (indices into `matches`), in that order, with their confidences where
// they have them.
CandidateMatches SelectMatches(const CandidateMatches& matches, const std::vector<size_t>& chosen);

struct NearestNeighborOptions {
  // Lowe's ratio on descriptor distances, the best row's against the best row of another point (an
  // image's observations are one per point; other rows may hold several per point); 1 accepts
  // every best match.
  double ratio = 0.9;
  // Keep a match only when the query keypoint is also the observation's best match.
  bool mutual = true;

  void Check() const;
};

// Mutual nearest neighbours with the ratio test between unit query rows and unit `rows`, row r
// standing for point row_points[r]: for each query row its best row, kept when the best row of any
// other point is far enough behind (options.ratio) and, with options.mutual, when the query row is
// also that row's best. Matches in query row order.
CandidateMatches MatchNearestRows(const DescriptorMatrix& unit_query,
                                  const Eigen::Ref<const DescriptorMatrix>& rows,
                                  const uint32_t* row_points,
                                  const NearestNeighborOptions& options);

// Rows [first, first + count) of a set of rows as 8-bit codes, row-major (count x the queries'
// dimension), each row standing for its direction (map/point_descriptors.h): the rows need not all
// be held at once.
using RowCodeReader = std::function<std::vector<int8_t>(int64_t first, int64_t count)>;

// The number of matches MatchNearestRows gives between the queries at 7 bits and the code rows
// (code_kernels::CodeSimilarities), in each of several sets of num_rows rows that share many of
// them (the points that neighbouring database images see): each row's similarities to the queries
// are computed once for every set that holds it, where matching the sets one by one computes them
// once per set. The codes' products are exact integers, a quarter of a float row's bytes and
// twice the float product's rate; the queries' rounding moves a cosine by about 1e-3, and the
// counts only rank images. read_rows gives the rows a block at a time. sets[s] lists row indices
// in increasing order, each row standing for its own point. The queries are split over
// num_threads threads (<= 0: all cores). Throws std::invalid_argument for a row index past
// num_rows, a set out of order, or a block of another size than asked for.
std::vector<int> CountNearestRowMatches(const DescriptorMatrix& unit_query, int64_t num_rows,
                                        const RowCodeReader& read_rows,
                                        const std::vector<std::vector<uint32_t>>& sets,
                                        const NearestNeighborOptions& options, int num_threads);

class NearestNeighborMatcher {
 public:
  // Groups the scene's observation descriptors by image, as unit rows, once; the scene may go
  // away afterwards. A scene without observations gives an empty matcher.
  explicit NearestNeighborMatcher(const Scene& scene);

  bool empty() const { return unit_descriptors_.rows() == 0; }
  // The matches of unit query descriptors (UnitRows) against database image `image_index`.
  CandidateMatches Match(const DescriptorMatrix& unit_query, uint32_t image_index,
                         const NearestNeighborOptions& options) const;

 private:
  // Observations of image i are rows [offsets_[i], offsets_[i + 1]).
  std::vector<uint32_t> offsets_;
  DescriptorMatrix unit_descriptors_;
  std::vector<uint32_t> point_indices_;
};

}  // namespace hscloc
