// Loading Aachen-style query lists with their features, and localizing a whole list into a
// submission file (`hscloc localize`), resumable.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <filesystem>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include "localization/localizer.h"
#include "localization/stage_timings.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"

namespace hscloc {

// Global descriptors by image name (ReadH5GlobalDescriptors).
using GlobalDescriptorMap = std::unordered_map<std::string, Eigen::VectorXf>;

// The queries of a list with their local features (and global descriptors, when given), in list
// order, at most `limit` of them. Throws std::invalid_argument naming the list or the feature
// source when a query has no features or no global descriptor.
std::vector<LocalizationQuery> LoadQueries(const std::filesystem::path& list,
                                           const FeatureReader& features,
                                           const GlobalDescriptorMap* global_descriptors = nullptr,
                                           size_t limit = std::numeric_limits<size_t>::max());
// One query of a list entry.
LocalizationQuery LoadQuery(const QueryWithIntrinsics& entry, const FeatureReader& features,
                            const GlobalDescriptorMap* global_descriptors = nullptr);

struct QueryListRunOptions {
  // The submission (NAME QW QX QY QZ TX TY TZ, basenames); failures go to `<out>.failures.txt`.
  std::filesystem::path out;
  // When set, one CSV line per query: its name, whether it was localized, its keypoints, the
  // retrieval rounds, the inliers, and the milliseconds of every stage (kStageFields); appended to
  // when resuming.
  std::filesystem::path timings_out;
  // Keep the queries already in `out` (a half-written last line is dropped) and append the rest.
  bool resume = false;
  // Queries localized in parallel, one core each; <= 0: all cores.
  int num_threads = 0;
  bool show_progress = true;

  void Check() const;
};

struct QueryListRunSummary {
  size_t num_queries = 0;  // in the lists
  size_t num_skipped = 0;  // already in `out` when resuming
  size_t num_localized = 0;
  size_t num_failed = 0;        // still written (the top-1 retrieved image's pose), and listed
  size_t num_with_votes = 0;    // queries that had a round of retrieval by point votes
  size_t num_won_by_votes = 0;  // localized queries whose winning candidate came from the votes
  // Localized queries whose winning candidate came from the points' mean descriptors (the
  // network's last resort, LocalizerOptions::nearest_point_candidates).
  size_t num_won_by_nearest_points = 0;
  std::filesystem::path failures_path;
  int num_threads = 0;
  double seconds = 0;
  StageTimingAccumulator timings;
};

// Localizes every query not yet in the submission and writes one line per query as it finishes,
// so that an interrupted run loses at most the queries in flight. Every query is checked for
// features (and global descriptors) before the first is localized. Throws std::invalid_argument
// for bad options or inputs; the first exception of any query stops the run and is rethrown.
QueryListRunSummary RunQueryList(const Localizer& localizer,
                                 const std::vector<QueryWithIntrinsics>& queries,
                                 const FeatureReader& features,
                                 const GlobalDescriptorMap* global_descriptors,
                                 const QueryListRunOptions& options);

}  // namespace hscloc
