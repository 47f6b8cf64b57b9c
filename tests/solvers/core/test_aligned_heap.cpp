// The programs' operator new (solvers/core/aligned_heap.cpp): blocks of a packet or more on a
// 64-byte boundary, and so a solve that does not depend on where the heap puts its buffers.
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "robust/backend_registry.h"
#include "solvers/problem/pose_graph_problem.h"
#include "tests/robust/dataset_prefix.h"

namespace loopd {
namespace {

TEST(AlignedHeap, BlocksOfAPacketOrMoreStartOnA64ByteBoundary) {
  std::vector<std::unique_ptr<char[]>> small;  // shift malloc's placement between the checks
  for (std::size_t n = 64; n < 5000; n += 40) {
    small.emplace_back(new char[8 + n % 48]);
    const std::unique_ptr<double[]> block(new double[n / sizeof(double)]);
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(block.get()) % 64, 0u) << n << " bytes";
    const std::vector<double> v(n / sizeof(double));
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(v.data()) % 64, 0u) << n << " bytes";
  }
}

// Every form of new and delete, blocks on both sides of a packet, each written end to end:
// in the sanitizer build (which links this heap into this test alone) ASan reports a block
// shorter than asked or a free of anything malloc did not return, LeakSanitizer one never
// freed.
TEST(AlignedHeap, EveryFormFreesWhatItAllocated) {
  for (std::size_t n = 0; n < 300; n += 7) {
    char* plain = static_cast<char*>(::operator new(n));
    std::memset(plain, 1, n);
    ::operator delete(plain, n);
    char* array = new char[n + 1];
    std::memset(array, 2, n + 1);
    delete[] array;
    char* quiet = new (std::nothrow) char[n + 1];
    ASSERT_NE(quiet, nullptr);
    std::memset(quiet, 3, n + 1);
    ::operator delete[](quiet, std::nothrow);
    void* unsized = ::operator new(n, std::nothrow);
    ASSERT_NE(unsized, nullptr);
    ::operator delete(unsized);
  }
  volatile std::size_t huge = static_cast<std::size_t>(-1) - 8;  // past malloc's header room
  EXPECT_THROW((void)::operator new(huge), std::bad_alloc);
}

// Batch LM on intel's first 300 poses, solved again after blocks of other sizes were left on
// the heap before it: with glibc's 16-byte placement two answers differed in their last bits
// (13 and 11 of 24 output path lengths of loopd-solve); here every one is the same, bit for bit.
TEST(AlignedHeap, SolvesTheSameWhereverTheHeapPutsTheBuffers) {
  const PoseGraphProblem p = buildProblem(test::loadPrefix("intel.g2o:300"));
  std::vector<double> first;
  std::vector<std::unique_ptr<char[]>> pads;
  for (int pad = 0; pad < 12; ++pad) {
    pads.emplace_back(new char[8 + 16 * pad]);
    auto lm = makeBackend("lm");
    lm->update(wholeProblemUpdate(p));
    const Values& x = lm->estimate();
    const std::vector<double> bits(x.data(0), x.data(0) + x.size() * kValueStride);
    if (pad == 0)
      first = bits;
    else
      EXPECT_EQ(std::memcmp(bits.data(), first.data(), bits.size() * sizeof(double)), 0)
          << "pad " << pad;
  }
}

}  // namespace
}  // namespace loopd
