#include "localization/pooled_matches.h"

#include <algorithm>

#include "util/check.h"

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
    const size_t expected_confidences = confident ? part->size() : 0;
    THROW_CHECK_MSG(part->confidences.size() == expected_confidences,
                    "UniteMatches: a part of {} matches has {} confidences ({} expected: all parts "
                    "have confidences or none)",
                    part->size(), part->confidences.size(), expected_confidences);
    total += part->size();
  }

  struct Entry {
    int keypoint;
    uint32_t point;
    float confidence;
  };
  std::vector<Entry> entries;
  entries.reserve(total);
  for (const CandidateMatches* part : parts) {
    for (size_t i = 0; i < part->size(); ++i) {
      entries.push_back(
          {part->keypoints[i], part->point_indices[i], confident ? part->confidences[i] : 0.0f});
    }
  }
  // Highest confidence first within a pair, so that the first of each run is the one kept.
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    if (a.keypoint != b.keypoint) return a.keypoint < b.keypoint;
    if (a.point != b.point) return a.point < b.point;
    return a.confidence > b.confidence;
  });
  CandidateMatches united;
  for (size_t i = 0; i < entries.size(); ++i) {
    if (i > 0 && entries[i].keypoint == entries[i - 1].keypoint &&
        entries[i].point == entries[i - 1].point) {
      continue;
    }
    united.keypoints.push_back(entries[i].keypoint);
    united.point_indices.push_back(entries[i].point);
    if (confident) united.confidences.push_back(entries[i].confidence);
  }
  return united;
}

}  // namespace hscloc
