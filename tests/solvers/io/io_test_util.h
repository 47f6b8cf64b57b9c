#pragma once
// Helpers shared by the reader and writer tests: dataset paths and scratch files.
#include <string>

#include "solvers/io/dataset.h"

namespace loopd::io::test {

/// `name` inside ../shared/datasets.
std::string datasetPath(const std::string& name);

/// A file in the system temp folder, unique per process and call, removed on destruction.
class ScratchFile {
 public:
  explicit ScratchFile(const std::string& suffix = ".g2o");
  ScratchFile(const std::string& content, const std::string& suffix);
  ~ScratchFile();
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

std::string readText(const std::string& path);

/// Every vertex and edge equal bit for bit (values, information, ids, types, edge indices).
void expectSameGraph(const Dataset& a, const Dataset& b);

}  // namespace loopd::io::test
