// Victoria Park (GTSAM's examples/Data/victoria_park.txt):
//   ODOMETRY a b dx dy dθ C11 C12 C13 C22 C23 C33
//   LANDMARK pose landmark dx dy Cxx Cxy Cyy
// Covariances, upper triangle row by row, stored inverted as information. No vertex lines;
// landmark ids are their own namespace.
#include <string_view>

#include "solvers/io/dataset_builder.h"
#include "solvers/io/dataset_reader.h"
#include "solvers/io/format_tags.h"
#include "solvers/io/records.h"

namespace loopd::io {

namespace {

constexpr std::string_view kOdometry = "ODOMETRY", kLandmark = "LANDMARK";
constexpr auto kCovariance = detail::Uncertainty::Covariance;

}  // namespace

bool detail::isVictoriaTag(std::string_view tag) { return tag == kOdometry || tag == kLandmark; }

Dataset parseVictoria(std::string_view text, const std::string& name) {
  detail::LineScanner in(name, text);
  detail::DatasetBuilder out(name, "victoria", /*landmarkIdsShared=*/false);
  while (in.next()) {
    if (in.tag() == kOdometry) {
      out.addEdge(in, detail::readEdge(in, EdgeType::BetweenSE2, kCovariance));
    } else if (in.tag() == kLandmark) {
      out.addEdge(in, detail::readEdge(in, EdgeType::PosePoint2, kCovariance));
    } else {
      in.fail("unknown Victoria Park tag " + detail::quoted(in.tag()));
    }
  }
  return out.finish();
}

}  // namespace loopd::io
