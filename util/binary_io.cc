#include "util/binary_io.h"

namespace hscloc {

std::string ReadBinaryCString(std::istream& stream, const std::string& what, size_t max_length) {
  std::string text;
  for (;;) {
    const char c = ReadBinary<char>(stream, what);
    if (c == '\0') return text;
    if (text.size() == max_length) {
      ThrowInvalidArgument("{}: string longer than {} characters (no terminating NUL)", what,
                           max_length);
    }
    text.push_back(c);
  }
}

}  // namespace hscloc
