/* sabre-rcl's build probe: fails to compile when an rcl, rcutils or rmw declaration the crate calls
 * differs from what src/lib.rs declares, and prints the layouts and constants the crate uses. */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <rcl/publisher.h>
#include <rcl/subscription.h>
#include <rcl/types.h>
#include <rcutils/allocator.h>
#include <rcutils/types/rcutils_ret.h>
#include <rcutils/types/uint8_array.h>
#include <rmw/types.h>

#define SAME(a, b) __builtin_types_compatible_p(__typeof__(a), b)
#define FIELD(type, field) (((type *)0)->field)

/* The five functions, with the signatures src/lib.rs gives them (handles as opaque pointers). */
_Static_assert(SAME(rcl_take_serialized_message,
                    rcl_ret_t(const rcl_subscription_t *, rcl_serialized_message_t *, rmw_message_info_t *,
                              rmw_subscription_allocation_t *)),
               "rcl_take_serialized_message's signature");
_Static_assert(SAME(rcl_publish_serialized_message,
                    rcl_ret_t(const rcl_publisher_t *, const rcl_serialized_message_t *, rmw_publisher_allocation_t *)),
               "rcl_publish_serialized_message's signature");
_Static_assert(SAME(rcutils_uint8_array_init,
                    rcutils_ret_t(rcutils_uint8_array_t *, size_t, const rcutils_allocator_t *)),
               "rcutils_uint8_array_init's signature");
_Static_assert(SAME(rcutils_uint8_array_fini, rcutils_ret_t(rcutils_uint8_array_t *)),
               "rcutils_uint8_array_fini's signature");
_Static_assert(SAME(rcutils_get_default_allocator, rcutils_allocator_t(void)),
               "rcutils_get_default_allocator's signature");

/* The return codes are 32-bit integers (i32 in Rust). */
_Static_assert(SAME(rcl_ret_t, int32_t), "rcl_ret_t is int32_t");
_Static_assert(SAME(rcutils_ret_t, int) && sizeof(int) == 4, "rcutils_ret_t is a 32-bit int");

/* The fields src/lib.rs reads and writes, with their types. */
_Static_assert(SAME(rcl_serialized_message_t, rcutils_uint8_array_t), "rcl_serialized_message_t");
_Static_assert(SAME(FIELD(rcutils_uint8_array_t, buffer), uint8_t *), "uint8_array.buffer");
_Static_assert(SAME(FIELD(rcutils_uint8_array_t, buffer_length), size_t), "uint8_array.buffer_length");
_Static_assert(SAME(FIELD(rcutils_uint8_array_t, buffer_capacity), size_t), "uint8_array.buffer_capacity");
_Static_assert(SAME(FIELD(rcutils_uint8_array_t, allocator), rcutils_allocator_t), "uint8_array.allocator");
_Static_assert(SAME(FIELD(rcutils_allocator_t, state), void *), "allocator.state");
_Static_assert(sizeof(FIELD(rcutils_allocator_t, allocate)) == sizeof(void *), "allocator.allocate");
_Static_assert(sizeof(FIELD(rcutils_allocator_t, deallocate)) == sizeof(void *), "allocator.deallocate");
_Static_assert(sizeof(FIELD(rcutils_allocator_t, reallocate)) == sizeof(void *), "allocator.reallocate");
_Static_assert(sizeof(FIELD(rcutils_allocator_t, zero_allocate)) == sizeof(void *), "allocator.zero_allocate");
_Static_assert(SAME(FIELD(rmw_message_info_t, received_timestamp), int64_t), "message_info.received_timestamp");

#define CONST(name, value) printf("pub const %s: usize = %zu;\n", name, (size_t)(value))

int main(void) {
  CONST("ALLOCATOR_SIZE", sizeof(rcutils_allocator_t));
  CONST("ALLOCATOR_ALIGN", _Alignof(rcutils_allocator_t));
  CONST("ALLOCATOR_ALLOCATE", offsetof(rcutils_allocator_t, allocate));
  CONST("ALLOCATOR_DEALLOCATE", offsetof(rcutils_allocator_t, deallocate));
  CONST("ALLOCATOR_REALLOCATE", offsetof(rcutils_allocator_t, reallocate));
  CONST("ALLOCATOR_ZERO_ALLOCATE", offsetof(rcutils_allocator_t, zero_allocate));
  CONST("ALLOCATOR_STATE", offsetof(rcutils_allocator_t, state));
  CONST("ARRAY_SIZE", sizeof(rcutils_uint8_array_t));
  CONST("ARRAY_ALIGN", _Alignof(rcutils_uint8_array_t));
  CONST("ARRAY_BUFFER", offsetof(rcutils_uint8_array_t, buffer));
  CONST("ARRAY_BUFFER_LENGTH", offsetof(rcutils_uint8_array_t, buffer_length));
  CONST("ARRAY_BUFFER_CAPACITY", offsetof(rcutils_uint8_array_t, buffer_capacity));
  CONST("ARRAY_ALLOCATOR", offsetof(rcutils_uint8_array_t, allocator));
  CONST("MESSAGE_INFO_SIZE", sizeof(rmw_message_info_t));
  CONST("MESSAGE_INFO_ALIGN", _Alignof(rmw_message_info_t));
  CONST("MESSAGE_INFO_RECEIVED_TIMESTAMP", offsetof(rmw_message_info_t, received_timestamp));
  printf("pub const RET_OK: i32 = %d;\n", (int)RCL_RET_OK);
  printf("pub const RET_TAKE_FAILED: i32 = %d;\n", (int)RCL_RET_SUBSCRIPTION_TAKE_FAILED);
  printf("pub const RCUTILS_RET_OK: i32 = %d;\n", (int)RCUTILS_RET_OK);
  return 0;
}
