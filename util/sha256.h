// SHA-256 digests (OpenSSL), as lowercase hex.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

namespace hscloc {

std::string Sha256Hex(std::string_view bytes);
// Streams the file; throws std::invalid_argument naming it when it cannot be read.
std::string Sha256HexOfFile(const std::filesystem::path& path);

}  // namespace hscloc
