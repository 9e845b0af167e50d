// Helpers of hscloc-bench: progress lines and the command-line tools it runs as
// child processes, timed and with their peak memory.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace hscloc::bench {

// Prints "[seconds since start] message" to stderr.
void Step(const std::string& message);

struct ChildRun {
  double seconds = 0;
  double peak_rss_mb = 0;
};

// Runs `args` (args[0] found on PATH) with stdout and stderr into `log`; throws
// std::runtime_error with the log's tail when it cannot start or exits non-zero.
ChildRun RunChild(const std::vector<std::string>& args, const std::filesystem::path& log);
// Whether `program` is on PATH.
bool CanRun(const std::string& program);

// Resident memory of this process.
double ResidentMegabytes();
// Bytes of the regular files under `dir`, leaving out files named in `exclude`.
uint64_t DirectoryBytes(const std::filesystem::path& dir,
                        const std::vector<std::string>& exclude = {});
std::string Megabytes(double bytes);

}  // namespace hscloc::bench
