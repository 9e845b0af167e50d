// Logging set-up. Code logs through spdlog directly (spdlog::info, ...); this sets the sink and
// level once per process.
#pragma once

#include <spdlog/spdlog.h>

#include <string>

namespace hscloc {

// Installs a stderr logger with timestamps and the given level ("trace", "debug", "info", "warn",
// "error", "off"). Throws std::invalid_argument for an unknown level name.
void SetupLogging(const std::string& level = "info");

}  // namespace hscloc
