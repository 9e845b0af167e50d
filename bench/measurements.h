// What hscloc-bench measures against the machine's limit: the fp32 matrix-product peak, the
// network against its FLOP floor, end-to-end latency per stage, and the server's throughput.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <vector>

#include "localization/localizer.h"

namespace hscloc::bench {

// The fp32 GEMM rate of libtorch (all cores) and of hscloc's CPU kernels.
nlohmann::json MeasureGemmPeaks();
// The network's Predict at N = 2000, K = 10 against the FLOP floor of `peaks`.
nlohmann::json NetworkAgainstFloor(const Localizer& localizer, const LocalizationQuery& query,
                                   const nlohmann::json& peaks);
// Per-stage latency over keypoint counts, retrieved images and candidate searches.
nlohmann::json LatencyGrid(const Localizer& localizer,
                           const std::vector<LocalizationQuery>& queries);
// Requests per second over loopback for 1 .. 8 concurrent clients, against the worker pool's
// ideal.
nlohmann::json ServerThroughput(const std::filesystem::path& bundle,
                                const std::vector<LocalizationQuery>& queries);

}  // namespace hscloc::bench
