#pragma once
// Which tags each reader understands, so readDataset can pick the reader from the first tag
// without a second copy of the tag lists. Internal to the readers.
#include <string_view>

namespace loopd::io::detail {

bool isG2oTag(std::string_view tag);
bool isToroTag(std::string_view tag);
bool isVictoriaTag(std::string_view tag);

}  // namespace loopd::io::detail
