#include "util/sha256.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <random>
#include <stdexcept>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// Known answers from FIPS 180-2, appendix B.
TEST(Sha256, MatchesFips180KnownVectors) {
  EXPECT_EQ(Sha256Hex(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
  EXPECT_EQ(Sha256Hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
  EXPECT_EQ(Sha256Hex("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
  EXPECT_EQ(Sha256Hex(std::string(1000000, 'a')),
            "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

TEST(Sha256, FileDigestEqualsBytesDigest) {
  testing::TempDir dir;
  // Larger than the read chunk, and not a multiple of it, so the chunk boundary is exercised.
  std::string bytes(3 * (1 << 20) + 12345, '\0');
  std::mt19937 random(11);
  for (char& c : bytes) c = static_cast<char>(random());
  const auto path = dir / "blob.bin";
  std::ofstream(path, std::ios::binary)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  EXPECT_EQ(Sha256HexOfFile(path), Sha256Hex(bytes));

  const auto empty_path = dir / "empty.bin";
  std::ofstream(empty_path, std::ios::binary).flush();
  EXPECT_EQ(Sha256HexOfFile(empty_path), Sha256Hex(""));
}

TEST(Sha256, UnreadableFileNamesIt) {
  testing::TempDir dir;
  try {
    Sha256HexOfFile(dir / "absent.bin");
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("absent.bin"));
  }
}

}  // namespace
}  // namespace hscloc
