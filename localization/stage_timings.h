// Where a query's time goes, stage by stage (DESIGN.md's query path), and the one accumulator of
// those timings that every report uses.
#pragma once

#include <cstddef>
#include <vector>

namespace hscloc {

// Milliseconds per stage of one Localize call. `match_ms` is the matcher's time: the network or
// the nearest-neighbour search, whichever the options chose.
struct StageTimings {
  double retrieval_ms = 0;
  double match_ms = 0;
  double visibility_ms = 0;
  double pose_ms = 0;
  double total_ms = 0;
};

// Per-stage means over many queries and percentiles of their totals (util/statistics.h).
class StageTimingAccumulator {
 public:
  void Add(const StageTimings& timings);
  size_t count() const { return totals_ms_.size(); }
  // Zero for every stage when nothing was added.
  StageTimings Mean() const;
  // The `fraction` quantile of the total time; NaN when nothing was added.
  double TotalPercentileMs(double fraction) const;

 private:
  StageTimings sums_;
  std::vector<double> totals_ms_;
};

}  // namespace hscloc
