/* x.y for three double terms, added as numpy's einsum("ij,ij->i") adds them on this
 * host: DOT3_ORDER is probed there (clradcom/device/visibility.py: dot3_order) and
 * passed as -D, so a kernel's float64 geometry is the host reference's bit for bit.
 * The includer enables fp64 and turns contraction off. */
#ifndef CLRADCOM_DOT3_H
#define CLRADCOM_DOT3_H

#ifndef DOT3_ORDER
#error "DOT3_ORDER must be passed as -D by the host (clradcom/device/visibility.py)"
#endif

CLR_INLINE double dot3(double a0, double a1, double a2, double b0, double b1, double b2)
{
    double p0 = a0 * b0, p1 = a1 * b1, p2 = a2 * b2;
#if DOT3_ORDER == 0
    return (p0 + p1) + p2;
#elif DOT3_ORDER == 1
    return (p0 + p2) + p1;
#else
    return (p1 + p2) + p0;
#endif
}

#endif
