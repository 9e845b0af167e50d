// Checks of generated markup shared by the report tests: element counts and tag balance, so that
// tests assert structure instead of comparing whole documents.
#pragma once

#include <string>
#include <vector>

namespace hscloc::testing {

// Occurrences of `needle` in `text`.
inline size_t CountOf(const std::string& text, const std::string& needle) {
  size_t count = 0;
  for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1)) {
    ++count;
  }
  return count;
}

// The first problem with the nesting of elements in `markup` (an end tag that closes nothing or
// the wrong element, an element left open), or "" when every element is closed in order. Void
// elements of HTML (meta) and self-closed ones (`<circle/>`) need no end tag; `<!doctype>` is
// skipped.
inline std::string UnbalancedTag(const std::string& markup) {
  std::vector<std::string> open;
  for (size_t at = markup.find('<'); at != std::string::npos; at = markup.find('<', at + 1)) {
    const size_t end = markup.find('>', at);
    if (end == std::string::npos) return "unterminated tag at " + std::to_string(at);
    const std::string tag = markup.substr(at + 1, end - at - 1);
    if (tag.empty() || tag[0] == '!' || tag.back() == '/') continue;
    const bool closing = tag[0] == '/';
    const std::string name =
        tag.substr(closing ? 1 : 0, tag.find_first_of(" \n", closing ? 1 : 0) - (closing ? 1 : 0));
    if (name == "meta") continue;
    if (!closing) {
      open.push_back(name);
    } else if (open.empty() || open.back() != name) {
      return "</" + name + "> closes " + (open.empty() ? std::string("nothing") : open.back());
    } else {
      open.pop_back();
    }
  }
  return open.empty() ? "" : "<" + open.back() + "> left open";
}

}  // namespace hscloc::testing
