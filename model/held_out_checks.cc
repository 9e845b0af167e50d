// The held-out checks' rules: which observations are held out, when a drop is measurable, which
// network training hands back and whether it converged.
#include <algorithm>
#include <cmath>
#include <vector>

#include "model/trainer.h"
#include "util/check.h"
#include "util/random.h"

namespace hscloc {
namespace {

// Random stream key of the held-out split (util/random.h); model/training_batch.cc holds the
// batches'.
constexpr uint64_t kStreamHoldout = 0x686f6c64;  // "hold"

}  // namespace

bool MeasurablyBelow(double accuracy, double best, size_t check_sample) {
  const double standard_error =
      std::sqrt(best * (1 - best) / static_cast<double>(std::max<size_t>(1, check_sample)));
  return accuracy < best - 2 * standard_error;
}

// Only a drop the check can tell from sampling noise brings a trained network back: on a
// saturated curve (pooled point rows on the city, 99.1 to 99.3 % from the first check on) the
// first check would otherwise win by a tenth of a point, and with it a network that had seen a
// tenth of the noisy descriptors the later ones had. The untrained start is another matter: it is
// the data's own matcher (class means, or a soft vote of each point's views), which training has
// not improved on where no later check reached it, however close the last one came (Lund XFeat,
// four minutes: 80.4 % at the start, every later check 72.4-77.4 %, the last 76.1 %).
bool ReturnsBestNetwork(const std::vector<HeldOutCheck>& checks, size_t check_sample) {
  if (checks.empty()) return false;
  const auto best = std::max_element(checks.begin(), checks.end(),
                                     [](const HeldOutCheck& a, const HeldOutCheck& b) {
                                       return a.point_accuracy < b.point_accuracy;
                                     });
  if (MeasurablyBelow(checks.back().point_accuracy, best->point_accuracy, check_sample))
    return true;
  return best->iteration == 0 && best + 1 != checks.end() &&
         std::all_of(best + 1, checks.end(), [&](const HeldOutCheck& check) {
           return check.point_accuracy < best->point_accuracy;
         });
}

bool HeldOutConverged(const std::vector<double>& accuracies, const std::vector<double>& progress) {
  THROW_CHECK_EQ(accuracies.size(), progress.size());
  double before_last_quarter = -1;
  double in_last_quarter = -1;
  double best = 0;
  for (size_t i = 0; i < accuracies.size(); ++i) {
    double& best_of_part = progress[i] <= 0.75 ? before_last_quarter : in_last_quarter;
    best_of_part = std::max(best_of_part, accuracies[i]);
    best = std::max(best, accuracies[i]);
  }
  return accuracies.size() >= 2 && in_last_quarter - before_last_quarter < 0.05 * best;
}

bool IsHeldOutObservation(uint64_t index, double fraction, uint64_t seed) {
  const uint64_t hash = MixBits(MixBits(seed ^ kStreamHoldout) ^ MixBits(index));
  return static_cast<double>(hash >> 11) * 0x1.0p-53 < fraction;
}

std::vector<uint32_t> HeldOutObservations(const Scene& scene, double fraction, uint64_t seed) {
  std::vector<uint32_t> held_out;
  for (uint32_t i = 0; i < scene.NumObservations(); ++i) {
    if (IsHeldOutObservation(i, fraction, seed)) held_out.push_back(i);
  }
  return held_out;
}

}  // namespace hscloc
