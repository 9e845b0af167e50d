// Where a query's time goes, stage by stage (DESIGN.md's query path), and the one accumulator of
// those timings that every report uses.
#pragma once

#include <array>
#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace hscloc {

// Milliseconds per stage of one Localize call. `match_ms` is the matcher's time: the network or
// the nearest-neighbour search, whichever the options chose. Two of the figures are parts of
// another, so that the stages still add up to the total: `votes_ms` of `retrieval_ms`, and
// `refine_ms` of `pose_ms`.
struct StageTimings {
  double retrieval_ms = 0;  // the global descriptor and its index, and the votes' round
  double match_ms = 0;
  double visibility_ms = 0;
  double pose_ms = 0;  // RANSAC per candidate and the refinements after it
  double total_ms = 0;
  // The parts, after the stages so that {retrieval, match, visibility, pose, total} still
  // initializes the stages.
  double votes_ms = 0;   // of retrieval_ms: the network without an image id and the vote count
  double refine_ms = 0;  // of pose_ms: the round winner's rival keypoints and the pooled pose
  int rounds = 0;  // retrieval rounds evaluated: 1, then one for the votes and one deeper global
};

// The timings by name, in the order of the query path, for tables and CSV columns.
struct StageField {
  std::string_view name;
  double StageTimings::*milliseconds;
};
inline constexpr std::array<StageField, 7> kStageFields = {{
    {"retrieval", &StageTimings::retrieval_ms},
    {"votes", &StageTimings::votes_ms},
    {"match", &StageTimings::match_ms},
    {"visibility", &StageTimings::visibility_ms},
    {"pose", &StageTimings::pose_ms},
    {"refine", &StageTimings::refine_ms},
    {"total", &StageTimings::total_ms},
}};

// Every query's timings, their per-stage means and percentiles (util/statistics.h).
class StageTimingAccumulator {
 public:
  void Add(const StageTimings& timings);
  size_t count() const { return all_.size(); }
  const std::vector<StageTimings>& all() const { return all_; }
  // Zero for every stage when nothing was added; `rounds` is the mean rounded down.
  StageTimings Mean() const;
  // The `fraction` quantile of one stage's milliseconds (fraction 1: the slowest query); NaN when
  // nothing was added.
  double PercentileMs(double StageTimings::*stage, double fraction) const;
  double TotalPercentileMs(double fraction) const {
    return PercentileMs(&StageTimings::total_ms, fraction);
  }

 private:
  std::vector<StageTimings> all_;
};

// A plain-text table, one line per stage: mean, p50, p95 and max milliseconds per query.
std::string FormatStageTable(const StageTimingAccumulator& timings);

}  // namespace hscloc
