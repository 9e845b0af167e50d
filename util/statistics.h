// Summary statistics shared by every report (the localize summary, the demo, hscloc-bench), so
// that two reports of the same numbers agree.
#pragma once

#include <vector>

namespace hscloc {

// The `fraction` quantile (0 .. 1) by linear interpolation between order statistics (numpy's
// default): Percentile({1, 2, 3, 4}, 0.5) = 2.5. NaN for no values; throws std::invalid_argument
// for a fraction outside [0, 1].
double Percentile(std::vector<double> values, double fraction);
// NaN for no values.
double Mean(const std::vector<double>& values);

}  // namespace hscloc
