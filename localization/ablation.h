// Ablations of the Localizer (Li et al., CVPR 2020, Table 4 and the supplementary's top-K and
// visibility studies): the same queries localized under named variants of LocalizerOptions, with
// accuracy per condition, mean stage timings and what each switch acts on (candidates posed,
// matches kept) per variant and condition.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "localization/localizer.h"
#include "localization/pose_evaluation.h"
#include "localization/stage_timings.h"
#include "scene/query_io.h"

namespace hscloc {

// One configuration of the Localizer, named as a report shows it.
struct AblationVariant {
  std::string name;
  LocalizerOptions options;
};

// The paper's configuration (top-10 images retrieved by the global descriptor, visibility filter,
// the winning image's pose) first, then one switch changed at a time: top-1, no visibility filter,
// top-1 without the filter, visibility-masked decoding, a round of point votes after a weak
// retrieval, and with it the final pose pooled over the candidates that agree (the default).
std::vector<AblationVariant> StandardAblationVariants();

// The queries of one condition (day, night), with their features (LoadQueries).
struct AblationQuerySet {
  std::string condition;
  std::vector<LocalizationQuery> queries;
};

struct AblationOptions {
  // Accuracy is reported at these (position, rotation) thresholds.
  std::vector<PoseThreshold> thresholds = AachenThresholds();
  // Keep every query's PoseResult in the results (for pictures and tests); off, only summaries.
  bool keep_results = false;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

// One variant on one condition's queries.
struct AblationCell {
  std::string variant;
  std::string condition;
  ConditionAccuracy accuracy;
  StageTimingAccumulator timings;
  // Per query: retrieved candidates, candidates posed, and matches kept (after the visibility
  // filter) summed over the posed candidates.
  double mean_candidates = 0;
  double mean_candidates_evaluated = 0;
  double mean_matches = 0;
  std::vector<PoseResult> results;  // in query order, when AblationOptions::keep_results
};

struct AblationResults {
  std::vector<std::string> variants;    // in the order given
  std::vector<std::string> conditions;  // in the order given
  std::vector<AblationCell> cells;      // variant-major: cells[v * conditions.size() + c]

  // Throws std::invalid_argument naming the variant or condition that is not in the results.
  const AblationCell& At(const std::string& variant, const std::string& condition) const;
};

// Localizes every query set under every variant, one query after another (so that the timings are
// those of one core per query). Poses are compared with `ground_truth` by image basename; a failed
// query counts as a failure at every threshold. Throws std::invalid_argument for bad options, no
// or duplicate variant or condition names, a query without ground truth, or variant options the
// Localizer cannot serve.
AblationResults RunAblations(const Localizer& localizer,
                             const std::vector<AblationQuerySet>& query_sets,
                             const std::vector<NamedPose>& ground_truth,
                             const std::vector<AblationVariant>& variants,
                             const AblationOptions& options = {});

// Plain text: per variant, its name and FormatAccuracyTable over the conditions.
std::string FormatAblationTable(const AblationResults& results);
// Plain text (Markdown): per condition of `variant`, the mean milliseconds of each stage.
std::string FormatLatencyTable(const AblationResults& results, const std::string& variant);

}  // namespace hscloc
