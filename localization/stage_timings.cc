#include "localization/stage_timings.h"

#include <fmt/format.h>

#include "util/statistics.h"

namespace hscloc {

void StageTimingAccumulator::Add(const StageTimings& timings) { all_.push_back(timings); }

StageTimings StageTimingAccumulator::Mean() const {
  StageTimings mean;
  if (all_.empty()) return mean;
  const double count = static_cast<double>(all_.size());
  long rounds = 0;
  for (const StageTimings& timings : all_) {
    for (const StageField& field : kStageFields) {
      mean.*field.milliseconds += timings.*field.milliseconds / count;
    }
    rounds += timings.rounds;
  }
  mean.rounds = static_cast<int>(rounds / static_cast<long>(all_.size()));
  return mean;
}

double StageTimingAccumulator::PercentileMs(double StageTimings::*stage, double fraction) const {
  std::vector<double> values;
  values.reserve(all_.size());
  for (const StageTimings& timings : all_) values.push_back(timings.*stage);
  return Percentile(values, fraction);
}

std::string FormatStageTable(const StageTimingAccumulator& timings) {
  std::string table =
      fmt::format("{:<11} {:>9} {:>9} {:>9} {:>9}\n", "ms per query", "mean", "p50", "p95", "max");
  const StageTimings mean = timings.Mean();
  for (const StageField& field : kStageFields) {
    table += fmt::format("{:<11} {:>9.1f} {:>9.1f} {:>9.1f} {:>9.1f}\n", field.name,
                         mean.*field.milliseconds, timings.PercentileMs(field.milliseconds, 0.5),
                         timings.PercentileMs(field.milliseconds, 0.95),
                         timings.PercentileMs(field.milliseconds, 1.0));
  }
  return table;
}

}  // namespace hscloc
