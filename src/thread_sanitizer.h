// Happens-before hints for ThreadSanitizer around TBB task boundaries (docs/reliability.md).
// Debian's libtbb is not instrumented, so TSan does not see that a parallel_for's tasks start
// after the caller prepared their inputs, nor that the caller resumes after every task ended: it
// then flags the caller's later reads of what the tasks wrote (the statistics merge, the image)
// as races. These calls state those two real orderings and nothing more; they compile to nothing
// without -fsanitize=thread.
#pragma once

#if defined(__SANITIZE_THREAD__)
#define PENUMBRA_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define PENUMBRA_TSAN 1
#endif
#endif

#if defined(PENUMBRA_TSAN)
#include <sanitizer/tsan_interface.h>
#endif

namespace penumbra::detail {

/// Orders a fork or a join: release(key) before it on one side, acquire(key) after it on the
/// other. Use distinct keys for the fork and for the join, so that tasks are not ordered among
/// themselves (which would hide real races between them).
#if defined(PENUMBRA_TSAN)
inline void tsanRelease(const void* key) { __tsan_release(const_cast<void*>(key)); }
inline void tsanAcquire(const void* key) { __tsan_acquire(const_cast<void*>(key)); }
#else
inline void tsanRelease(const void*) {}
inline void tsanAcquire(const void*) {}
#endif

}  // namespace penumbra::detail
