#include "util/statistics.h"

#include <algorithm>
#include <cmath>

#include "util/check.h"

namespace hscloc {

double Percentile(std::vector<double> values, double fraction) {
  if (!(fraction >= 0 && fraction <= 1)) {
    ThrowInvalidArgument("Percentile: fraction {} is not in [0, 1]", fraction);
  }
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  const double position = fraction * (values.size() - 1);
  const size_t below = static_cast<size_t>(position);
  const size_t above = std::min(values.size() - 1, below + 1);
  return values[below] + (position - below) * (values[above] - values[below]);
}

double Mean(const std::vector<double>& values) {
  if (values.empty()) return std::nan("");
  double sum = 0;
  for (const double value : values) sum += value;
  return sum / values.size();
}

}  // namespace hscloc
