#include "io_test_util.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace loopd::io::test {

std::string datasetPath(const std::string& name) {
  return std::string(LOOPD_DATASETS_DIR) + "/" + name;
}

ScratchFile::ScratchFile(const std::string& suffix) {
  static std::atomic<int> counter{0};
  path_ = (std::filesystem::temp_directory_path() /
           ("loopd_io_" + std::to_string(::getpid()) + "_" + std::to_string(counter++) + suffix))
              .string();
}

ScratchFile::ScratchFile(const std::string& content, const std::string& suffix)
    : ScratchFile(suffix) {
  std::ofstream(path_, std::ios::binary) << content;
}

ScratchFile::~ScratchFile() {
  std::error_code ignored;
  std::filesystem::remove(path_, ignored);
}

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

namespace {

void expectSameVertices(const std::vector<Vertex>& a, const std::vector<Vertex>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].id, b[i].id) << "vertex " << i;
    EXPECT_EQ(a[i].type, b[i].type) << "vertex " << i;
    EXPECT_EQ(a[i].value, b[i].value) << "vertex " << a[i].id;
  }
}

}  // namespace

void expectSameGraph(const Dataset& a, const Dataset& b) {
  EXPECT_EQ(a.is3d, b.is3d);
  expectSameVertices(a.poses, b.poses);
  expectSameVertices(a.landmarks, b.landmarks);
  // TORO's EQUIV pairs come back as g2o edges after the others (RoundTrip.ToroEquivalences...).
  ASSERT_EQ(a.edges.size() + a.equivalences.size(), b.edges.size() + b.equivalences.size());
  for (std::size_t i = 0; i < a.edges.size(); ++i) {
    const Edge& x = a.edges[i];
    const Edge& y = b.edges[i];
    EXPECT_EQ(x.type, y.type) << "edge " << i;
    EXPECT_EQ(x.from, y.from) << "edge " << i;
    EXPECT_EQ(x.to, y.to) << "edge " << i;
    EXPECT_EQ(x.index, y.index) << "edge " << i;
    EXPECT_EQ(x.measurement, y.measurement) << "edge " << i;
    const int d = edgeDimension(x.type);
    EXPECT_TRUE(x.information.topLeftCorner(d, d) == y.information.topLeftCorner(d, d))
        << "edge " << i;
  }
}

}  // namespace loopd::io::test
