#include "util/logging.h"

#include <spdlog/sinks/stdout_color_sinks.h>

#include "util/check.h"

namespace hscloc {

void SetupLogging(const std::string& level) {
  const spdlog::level::level_enum parsed = spdlog::level::from_str(level);
  // from_str maps unknown names to "off"; only "off" itself may mean off.
  THROW_CHECK_MSG(parsed != spdlog::level::off || level == "off",
                  "unknown log level '{}' (trace, debug, info, warn, error, off)", level);
  // A second call (a tool that runs several stages, a test) changes the level of the same logger.
  std::shared_ptr<spdlog::logger> logger = spdlog::get("hscloc");
  if (logger == nullptr) logger = spdlog::stderr_color_mt("hscloc");
  logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
  logger->set_level(parsed);
  spdlog::set_default_logger(logger);
}

}  // namespace hscloc
