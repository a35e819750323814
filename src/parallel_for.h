// tbb::parallel_for over a range, with its fork and join stated to ThreadSanitizer
// (thread_sanitizer.h): the tasks see what the caller wrote before the loop, and the caller sees
// what every task wrote once the loop returns. Nothing orders the tasks among themselves, so a
// race between two of them is still reported. Without -fsanitize=thread this is parallel_for.
#pragma once

#include "thread_sanitizer.h"

#include <functional>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace penumbra::detail {

/// The body TBB's partitioner sees. Its type names none of the caller's: a lambda inside a
/// function template whose signature spells out an OpenVDB grid type makes TBB's task names
/// longer than TSan's symbolizer buffer, and a truncated name matches none of the
/// suppressions (.ci/tsan.supp) written for TBB's own functions. One call through a
/// std::function per chunk of the range.
template <class Range>
struct ParallelBody {
    const std::function<void(const Range&)>* run;
    const char* forkKey;
    const char* joinKey;
    void operator()(const Range& part) const {
        tsanAcquire(forkKey);
        (*run)(part);
        tsanRelease(joinKey);
    }
};

template <class Range, class Body>
void parallelFor(const Range& range, const Body& body) {
    const char forkKey = 0, joinKey = 0;
    const std::function<void(const Range&)> run = [&body](const Range& part) { body(part); };
    tsanRelease(&forkKey);
    tbb::parallel_for(range, ParallelBody<Range>{&run, &forkKey, &joinKey});
    tsanAcquire(&joinKey);
}

}  // namespace penumbra::detail
