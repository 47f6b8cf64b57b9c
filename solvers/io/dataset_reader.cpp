#include "solvers/io/dataset_reader.h"

#include "solvers/io/format_tags.h"
#include "solvers/io/line_scanner.h"

namespace loopd::io {

Dataset readDataset(const std::string& path) {
  const std::string text = detail::readWholeFile(path);
  return parseDataset(text, path);
}

Dataset parseDataset(std::string_view text, const std::string& name) {
  // A UTF-8 byte-order mark (editors on Windows write one) is not part of the first tag.
  constexpr std::string_view kByteOrderMark = "\xEF\xBB\xBF";
  if (text.substr(0, kByteOrderMark.size()) == kByteOrderMark)
    text.remove_prefix(kByteOrderMark.size());
  detail::LineScanner first(name, text);
  if (!first.next()) throw DatasetError(name, 0, "the file has no edges (it is empty)");
  const std::string_view tag = first.tag();
  if (detail::isG2oTag(tag)) return parseG2o(text, name);
  if (detail::isToroTag(tag)) return parseToro(text, name);
  if (detail::isVictoriaTag(tag)) return parseVictoria(text, name);
  first.fail("unknown tag " + detail::quoted(tag) + " (not g2o, TORO or Victoria Park)");
}

}  // namespace loopd::io
