// The cumulative error plot of a localization benchmark (as visuallocalization.net draws it).
#pragma once

#include <string>
#include <vector>

#include "localization/pose_evaluation.h"

namespace hscloc {

// A self-contained SVG: the cumulative share of queries against position error (log scale, left)
// and rotation error (log scale, right), one curve per condition, thresholds marked, a legend with
// each condition's query count.
std::string CumulativeErrorSvg(const std::vector<ConditionAccuracy>& accuracies,
                               const std::string& title);

}  // namespace hscloc
