#include "localization/ablation.h"

#include <fmt/format.h>

#include <unordered_set>

#include "util/check.h"

namespace hscloc {
namespace {

void CheckUniqueNames(const std::vector<std::string>& names, const char* what) {
  if (names.empty()) ThrowInvalidArgument("RunAblations: no {}", what);
  std::unordered_set<std::string> seen;
  for (const std::string& name : names) {
    if (name.empty()) ThrowInvalidArgument("RunAblations: a {} without a name", what);
    if (!seen.insert(name).second)
      ThrowInvalidArgument("RunAblations: two {} named '{}'", what, name);
  }
}

AblationCell RunCell(const Localizer& localizer, const AblationVariant& variant,
                     const AblationQuerySet& set, const std::vector<NamedPose>& ground_truth,
                     const AblationOptions& options) {
  AblationCell cell;
  cell.variant = variant.name;
  cell.condition = set.condition;
  std::vector<NamedPose> estimates;
  ConditionQueries condition{set.condition, {}};
  for (const LocalizationQuery& query : set.queries) {
    condition.basenames.insert(ImageBasename(query.name));
    PoseResult result = localizer.Localize(query, variant.options);
    if (result.success) estimates.push_back({query.name, result.cam_from_world});
    cell.timings.Add(result.timings);
    cell.mean_candidates += static_cast<double>(result.candidates.size());
    for (const LocalizationCandidate& candidate : result.candidates) {
      if (!candidate.evaluated) continue;
      cell.mean_candidates_evaluated += 1;
      cell.mean_matches += candidate.num_matches;
    }
    if (options.keep_results) cell.results.push_back(std::move(result));
  }
  const double count = std::max<double>(1, static_cast<double>(set.queries.size()));
  cell.mean_candidates /= count;
  cell.mean_candidates_evaluated /= count;
  cell.mean_matches /= count;
  cell.accuracy = SummarizeAccuracyByCondition(ComputePoseErrors(ground_truth, estimates),
                                               {condition}, options.thresholds)
                      .front();
  return cell;
}

}  // namespace

std::vector<AblationVariant> StandardAblationVariants() {
  std::vector<AblationVariant> variants(7);
  // The paper's pipeline retrieves with the global descriptor alone and keeps the winning image's
  // pose; each of the first five variants switches one thing of it, the sixth adds the votes'
  // round, the last is hscloc's default (with the deeper global round where the votes are weak
  // too, RANSAC sampling the network's most confident matches first, and the points' mean
  // descriptors where the network finds no pose).
  for (size_t i = 0; i < 6; ++i) {
    variants[i].options.final_pose = FinalPose::kWinner;
    variants[i].options.sample_by_confidence = false;
    variants[i].options.nearest_point_candidates = 0;
  }
  for (size_t i = 0; i < 5; ++i) variants[i].options.retrieval = RetrievalMode::kGlobal;
  variants[0].name = "top-10, visibility filter (paper)";
  variants[1].name = "top-1, visibility filter";
  variants[1].options.top_k = 1;
  variants[2].name = "top-10, no filter";
  variants[2].options.visibility_filter = false;
  variants[3].name = "top-1, no filter";
  variants[3].options.top_k = 1;
  variants[3].options.visibility_filter = false;
  variants[4].name = "top-10, visibility-masked decoding";
  variants[4].options.visibility_masked_decoding = true;
  variants[5].name = "top-10, then point votes";
  variants[5].options.retrieval = RetrievalMode::kGlobalThenVotes;
  variants[5].options.deeper_global_candidates = 0;
  variants[6].name = "top-10, then point votes, pooled final pose (default)";
  variants[6].options.retrieval = RetrievalMode::kGlobalThenVotes;
  variants[6].options.final_pose = FinalPose::kPooled;
  return variants;
}

void AblationOptions::Check() const {
  THROW_CHECK_MSG(!thresholds.empty(), "AblationOptions.thresholds is empty");
  for (const PoseThreshold& threshold : thresholds) {
    THROW_CHECK_MSG(threshold.position > 0 && threshold.rotation_deg > 0,
                    "AblationOptions.thresholds: ({} m, {} deg) is not positive",
                    threshold.position, threshold.rotation_deg);
  }
}

const AblationCell& AblationResults::At(const std::string& variant,
                                        const std::string& condition) const {
  for (const AblationCell& cell : cells) {
    if (cell.variant == variant && cell.condition == condition) return cell;
  }
  ThrowInvalidArgument("ablation results: no variant '{}' on condition '{}'", variant, condition);
}

AblationResults RunAblations(const Localizer& localizer,
                             const std::vector<AblationQuerySet>& query_sets,
                             const std::vector<NamedPose>& ground_truth,
                             const std::vector<AblationVariant>& variants,
                             const AblationOptions& options) {
  options.Check();
  AblationResults results;
  for (const AblationVariant& variant : variants) {
    variant.options.Check();
    results.variants.push_back(variant.name);
  }
  for (const AblationQuerySet& set : query_sets) results.conditions.push_back(set.condition);
  CheckUniqueNames(results.variants, "variants");
  CheckUniqueNames(results.conditions, "query sets");
  for (const AblationVariant& variant : variants) {
    for (const AblationQuerySet& set : query_sets) {
      results.cells.push_back(RunCell(localizer, variant, set, ground_truth, options));
    }
  }
  return results;
}

std::string FormatAblationTable(const AblationResults& results) {
  std::string text;
  for (const std::string& variant : results.variants) {
    std::vector<ConditionAccuracy> rows;
    for (const std::string& condition : results.conditions) {
      rows.push_back(results.At(variant, condition).accuracy);
    }
    text += variant + "\n" + FormatAccuracyTable(rows);
  }
  return text;
}

std::string FormatLatencyTable(const AblationResults& results, const std::string& variant) {
  std::string table =
      "| condition | retrieval | match | visibility | pose | total (ms, mean) |\n"
      "| --- | --- | --- | --- | --- | --- |\n";
  for (const std::string& condition : results.conditions) {
    const StageTimings mean = results.At(variant, condition).timings.Mean();
    table += fmt::format("| {} | {:.1f} | {:.1f} | {:.2f} | {:.1f} | {:.1f} |\n", condition,
                         mean.retrieval_ms, mean.match_ms, mean.visibility_ms, mean.pose_ms,
                         mean.total_ms);
  }
  return table;
}

}  // namespace hscloc
