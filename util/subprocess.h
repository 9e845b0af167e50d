// Running another program (COLMAP) to completion, its output kept in a log file.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hscloc {

// `program` when it names an executable file (it holds a '/'), else the first executable of that
// name on PATH; nullopt when there is none.
std::optional<std::filesystem::path> FindExecutable(const std::string& program);

// Runs `arguments` (arguments[0]: the executable's path, as FindExecutable gives it) without a
// shell, stdout and stderr into `log_path` (replaced), and waits for it. Returns its exit status,
// or 128 + the signal number when a signal ended it. Throws std::runtime_error when it cannot be
// started or the log cannot be created.
int RunProcess(const std::vector<std::string>& arguments, const std::filesystem::path& log_path);

// The last `max_lines` lines of a text file ("" when it cannot be read), for error messages.
std::string LastLines(const std::filesystem::path& path, int max_lines);

}  // namespace hscloc
