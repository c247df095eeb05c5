/* The reference through a computed include, its directive split by a line splice. */
#define REF "../../reference/kernels/shared/rt_packet.h"
#inc\
lude REF
