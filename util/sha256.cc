#include "util/sha256.h"

#include <openssl/evp.h>

#include <array>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <vector>

#include "util/check.h"

namespace hscloc {
namespace {

struct DigestContextDeleter {
  void operator()(EVP_MD_CTX* context) const { EVP_MD_CTX_free(context); }
};
using DigestContext = std::unique_ptr<EVP_MD_CTX, DigestContextDeleter>;

DigestContext NewSha256Context() {
  DigestContext context(EVP_MD_CTX_new());
  if (context == nullptr || EVP_DigestInit_ex(context.get(), EVP_sha256(), nullptr) != 1) {
    throw std::runtime_error("SHA-256: cannot initialize the OpenSSL digest");
  }
  return context;
}

void Update(EVP_MD_CTX* context, const char* data, size_t size) {
  if (EVP_DigestUpdate(context, data, size) != 1) {
    throw std::runtime_error("SHA-256: OpenSSL digest update failed");
  }
}

std::string FinalHex(EVP_MD_CTX* context) {
  std::array<unsigned char, EVP_MAX_MD_SIZE> digest;
  unsigned int size = 0;
  if (EVP_DigestFinal_ex(context, digest.data(), &size) != 1) {
    throw std::runtime_error("SHA-256: OpenSSL digest finalization failed");
  }
  static constexpr char kHexDigits[] = "0123456789abcdef";
  std::string hex(2 * size, '0');
  for (unsigned int i = 0; i < size; ++i) {
    hex[2 * i] = kHexDigits[digest[i] >> 4];
    hex[2 * i + 1] = kHexDigits[digest[i] & 0xf];
  }
  return hex;
}

}  // namespace

std::string Sha256Hex(std::string_view bytes) {
  DigestContext context = NewSha256Context();
  Update(context.get(), bytes.data(), bytes.size());
  return FinalHex(context.get());
}

std::string Sha256HexOfFile(const std::filesystem::path& path) {
  std::ifstream file(path, std::ios::binary);
  if (!file) ThrowInvalidArgument("cannot open {} to compute its SHA-256", path.string());
  DigestContext context = NewSha256Context();
  // Chunked so that multi-hundred-megabyte blobs are hashed without holding them in memory.
  std::vector<char> buffer(1 << 20);
  while (file) {
    file.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    Update(context.get(), buffer.data(), static_cast<size_t>(file.gcount()));
  }
  if (file.bad())
    ThrowInvalidArgument("error while reading {} to compute its SHA-256", path.string());
  return FinalHex(context.get());
}

}  // namespace hscloc
