#include "util/check.h"

namespace hscloc::internal {

void ThrowCheckFailure(const char* file, int line, const std::string& what) {
  throw std::invalid_argument(fmt::format("{}:{}: {}", file, line, what));
}

}  // namespace hscloc::internal
