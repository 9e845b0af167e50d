#include "localization/pooled_matches.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "util/check.h"
#include "util/radix_sort.h"

namespace hscloc {

CandidateMatches UniteMatches(const std::vector<const CandidateMatches*>& parts) {
  const bool confident = std::any_of(parts.begin(), parts.end(), [](const CandidateMatches* part) {
    return part != nullptr && !part->confidences.empty();
  });
  size_t total = 0;
  for (const CandidateMatches* part : parts) {
    THROW_CHECK_MSG(part != nullptr, "UniteMatches: a part is null");
    THROW_CHECK_MSG(part->point_indices.size() == part->size(),
                    "UniteMatches: a part has {} keypoints but {} points", part->size(),
                    part->point_indices.size());
    THROW_CHECK_MSG(
        part->confidences.empty() || part->confidences.size() == part->size(),
        "UniteMatches: a part of {} matches has {} confidences (one per match, or none)",
        part->size(), part->confidences.size());
    total += part->size();
  }

  // Pairs grouped by one linear-time sort of (keypoint, point) packed in an integer: a comparison
  // sort of the pool took 0.7 ms of a city query's pose stage. A pair keeps its most confident
  // entry (ties: the first).
  std::vector<std::pair<int64_t, int64_t>> by_pair;  // (keypoint, point) packed; entry
  std::vector<float> confidences;                    // by entry
  by_pair.reserve(total);
  if (confident) confidences.reserve(total);
  for (const CandidateMatches* part : parts) {
    for (size_t i = 0; i < part->size(); ++i) {
      THROW_CHECK_MSG(part->keypoints[i] >= 0, "UniteMatches: keypoint {} is negative",
                      part->keypoints[i]);
      const auto key = static_cast<int64_t>(part->keypoints[i]) << 32 | part->point_indices[i];
      by_pair.emplace_back(key, static_cast<int64_t>(by_pair.size()));
      // Nearest-neighbour matches (the localizer's last round) carry no confidence: beside the
      // network's, each counts as the least confident.
      if (confident) confidences.push_back(part->confidences.empty() ? 0.0f : part->confidences[i]);
    }
  }
  std::vector<std::pair<int64_t, int64_t>> scratch;
  StableSortByKey(by_pair, scratch);
  CandidateMatches united;
  for (size_t i = 0; i < by_pair.size(); ++i) {
    const float confidence = confident ? confidences[by_pair[i].second] : 0.0f;
    if (i > 0 && by_pair[i].first == by_pair[i - 1].first) {
      if (confident && confidence > united.confidences.back())
        united.confidences.back() = confidence;
      continue;
    }
    united.keypoints.push_back(static_cast<int>(by_pair[i].first >> 32));
    united.point_indices.push_back(static_cast<uint32_t>(by_pair[i].first & 0xffffffff));
    if (confident) united.confidences.push_back(confidence);
  }
  return united;
}

}  // namespace hscloc
