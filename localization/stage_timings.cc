#include "localization/stage_timings.h"

#include "util/statistics.h"

namespace hscloc {

void StageTimingAccumulator::Add(const StageTimings& timings) {
  sums_.retrieval_ms += timings.retrieval_ms;
  sums_.match_ms += timings.match_ms;
  sums_.visibility_ms += timings.visibility_ms;
  sums_.pose_ms += timings.pose_ms;
  sums_.total_ms += timings.total_ms;
  totals_ms_.push_back(timings.total_ms);
}

StageTimings StageTimingAccumulator::Mean() const {
  if (totals_ms_.empty()) return {};
  const double count = static_cast<double>(totals_ms_.size());
  return {sums_.retrieval_ms / count, sums_.match_ms / count, sums_.visibility_ms / count,
          sums_.pose_ms / count, sums_.total_ms / count};
}

double StageTimingAccumulator::TotalPercentileMs(double fraction) const {
  return Percentile(totals_ms_, fraction);
}

}  // namespace hscloc
