// The program's operator new, replaced: every block of 64 bytes or more starts on a 64-byte
// boundary (one AVX-512 packet). Linked into the programs that solve (loopd-solve, loopd,
// loopd-eval, the tests) by loopd_use_aligned_heap() in CMake, not into the libraries.
//
// Why: Eigen vectorizes a reduction over a buffer of unknown alignment (a Map over a
// std::vector, a dense clique block) by first peeling the elements before its first aligned
// packet, so the order of the sum, and its last bits, follow the buffer's address modulo 64.
// glibc's malloc gives 16-byte alignment, and where the heap puts a block moves with anything
// allocated before it: the same file solved twice by the same binary ended differently when
// only the output path's length differed (lm on intel's first 300 poses: two answers over 24
// path lengths; risam on intel + 1000 random, seed 3: a different map). With this, one answer.
// Smaller blocks keep malloc's 16-byte alignment: they hold less than one packet, so Eigen
// sums them element by element in order anyway.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>

namespace {

constexpr std::size_t kPacketBytes = 64;
constexpr std::size_t kHeaderBytes = alignof(std::max_align_t);  // room for the offset
static_assert(kHeaderBytes >= sizeof(std::size_t) && kPacketBytes % kHeaderBytes == 0);

// malloc's block, the caller's block placed after a header that holds its offset from
// malloc's: blocks of a packet or more on the next 64-byte boundary, smaller ones right after
// the header. posix_memalign did the same but was slower (sphere2500 isam2 online +8%).
void* allocate(std::size_t n) {
  const bool large = n >= kPacketBytes;
  // malloc's blocks are aligned to max_align_t (the header's size), so header and padding to
  // the next boundary together take at most one packet.
  const std::size_t extra = large ? kPacketBytes : kHeaderBytes;
  if (n > static_cast<std::size_t>(-1) - extra) throw std::bad_alloc();
  char* raw = static_cast<char*>(std::malloc(n + extra));
  if (raw == nullptr) throw std::bad_alloc();
  std::uintptr_t at = reinterpret_cast<std::uintptr_t>(raw) + kHeaderBytes;
  if (large) at = (at + kPacketBytes - 1) & ~static_cast<std::uintptr_t>(kPacketBytes - 1);
  char* block = reinterpret_cast<char*>(at);
  reinterpret_cast<std::size_t*>(block)[-1] = static_cast<std::size_t>(block - raw);
  return block;
}

void release(void* p) noexcept {
  if (p == nullptr) return;
  char* block = static_cast<char*>(p);
  std::free(block - reinterpret_cast<const std::size_t*>(block)[-1]);
}

}  // namespace

void* operator new(std::size_t n) { return allocate(n); }
void* operator new[](std::size_t n) { return allocate(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  try {
    return allocate(n);
  } catch (const std::bad_alloc&) {
    return nullptr;
  }
}
void* operator new[](std::size_t n, const std::nothrow_t& t) noexcept { return operator new(n, t); }
void operator delete(void* p) noexcept { release(p); }
void operator delete[](void* p) noexcept { release(p); }
void operator delete(void* p, std::size_t) noexcept { release(p); }
void operator delete[](void* p, std::size_t) noexcept { release(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { release(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { release(p); }
