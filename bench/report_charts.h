// The performance report's SVG charts: cost against map size, and accuracy against training time.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace hscloc::bench {

// Query time, training time and bundle size per preset (the report's "scale" rows).
std::string ScaleSvg(const nlohmann::json& scale);
// Held-out accuracy and localization of each preset against training time.
std::string TrainingCurveSvg(const nlohmann::json& scale);

}  // namespace hscloc::bench
