// The page `hscloc demo` writes: accuracy through the server, the cumulative error curves beside a
// top view of the map and the queries, the ablations, the latency per stage and pictures of
// inlier matches.
#pragma once

#include <string>
#include <vector>

#include "localization/ablation.h"
#include "localization/pose_evaluation.h"
#include "report/top_view.h"

namespace hscloc {

struct DemoReport {
  std::string title = "hscloc demo";
  std::string summary;  // one paragraph under the title: the data set, the total time
  // Accuracy of the queries localized through the server (hscloc-client batch).
  std::vector<ConditionAccuracy> accuracy;
  // The same queries' truths and estimates, drawn on the map.
  TopViewContent top_view;
  // In-process runs of the Localizer's variants; the latency table shows `latency_variant`.
  AblationResults ablations;
  std::string latency_variant;
  // MatchPictureSvg of a few queries.
  std::vector<std::string> match_pictures;
};

// A self-contained HTML page. Throws std::invalid_argument when the ablations lack the latency
// variant.
std::string RenderDemoReport(const DemoReport& report);

}  // namespace hscloc
