// The localization results as HTML tables (report/html.h): accuracy per condition, the ablations
// and the latency per stage.
#pragma once

#include <string>
#include <vector>

#include "localization/ablation.h"
#include "localization/pose_evaluation.h"
#include "report/html.h"

namespace hscloc {

// One row per condition: queries, estimated, the share within each threshold (%), median position
// and rotation errors.
HtmlTable AccuracyTable(const std::vector<ConditionAccuracy>& accuracies,
                        const std::string& caption);

// One row per variant and condition: the share within each threshold (%), median position error,
// and per query the candidates posed, the matches kept and the mean total time.
HtmlTable AblationTable(const AblationResults& results, const std::string& caption);

// One row per condition of `variant`: mean milliseconds per stage, and the median and 90th
// percentile of the total. Throws std::invalid_argument when the results lack the variant.
HtmlTable LatencyTable(const AblationResults& results, const std::string& variant,
                       const std::string& caption);

}  // namespace hscloc
