/* x.y for three float64 terms, added as numpy's einsum("ij,ij->i") adds them on this
 * host: DOT3_ORDER is probed there (clradcom/device/visibility.py: dot3_order) and
 * passed as -D, so a kernel's float64 geometry is the host reference's bit for bit. In
 * precise.h's preal: double with fp64; without, the double-float follows the same order
 * (its result is then the host's to ~1e-14, whatever the order). The includer turns
 * contraction off. */
#ifndef CLRADCOM_DOT3_H
#define CLRADCOM_DOT3_H

#include "precise.h"

#ifndef DOT3_ORDER
#error "DOT3_ORDER must be passed as -D by the host (clradcom/device/visibility.py)"
#endif

PR_INLINE preal dot3(preal a0, preal a1, preal a2, preal b0, preal b1, preal b2)
{
    preal p0 = pr_mul(a0, b0), p1 = pr_mul(a1, b1), p2 = pr_mul(a2, b2);
#if DOT3_ORDER == 0
    return pr_add(pr_add(p0, p1), p2);
#elif DOT3_ORDER == 1
    return pr_add(pr_add(p0, p2), p1);
#else
    return pr_add(pr_add(p1, p2), p0);
#endif
}

#endif
