// A rosbridge client for tests, on the real npm `roslib` (the dashboard's
// assets/node_modules). It prints one JSON object a line on stdout, each
// with an "event" field, and exits 0 when its script is done.
//
//   node roslib_client.mjs URL ROBOT MODE
//
// MODE "drive": list the topics, ask the ROS version, subscribe
//   /ROBOT/odom, /ROBOT/scan, /map and /tf, then publish /ROBOT/cmd_vel (0.3 m/s
//   forward) every 100 ms for 1.5 s, wait 0.6 s, and report the first and
//   last odometry poses.
// MODE "denied": the same publishing, expecting status errors (no token).

const roslibUrl = new URL("../../../assets/node_modules/roslib/dist/RosLib.js", import.meta.url);
const ROSLIB = await import(roslibUrl.href);

const [url, robot, mode = "drive"] = process.argv.slice(2);
const print = (event, data = {}) => console.log(JSON.stringify({ event, ...data }));
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

const deadline = setTimeout(() => {
  print("timeout");
  process.exit(2);
}, 20000);

const ros = new ROSLIB.Ros({});

// every status the server sends, whatever its id
const handle = ros.handleMessage.bind(ros);
ros.handleMessage = (message) => {
  if (message.op === "status") print("status", { level: message.level, msg: message.msg, id: message.id ?? null });
  handle(message);
};

await new Promise((resolve, reject) => {
  ros.on("connection", resolve);
  ros.on("error", (e) => reject(new Error(`connection error: ${e?.message ?? e}`)));
  ros.on("close", () => reject(new Error("closed before connecting")));
  ros.connect(url).catch(reject);
}).catch((e) => {
  print("error", { message: e.message });
  process.exit(1);
});
print("connected");

const callService = (name, serviceType, args = {}) =>
  new Promise((resolve, reject) =>
    new ROSLIB.Service({ ros, name, serviceType }).callService(args, resolve, reject)
  );

const topics = await new Promise((resolve, reject) => ros.getTopics(resolve, reject));
print("topics", topics);
print("ros_version", await callService("/rosapi/get_ros_version", "rosapi_msgs/srv/GetROSVersion"));

const poses = [];
let firstScan = null;
const odom = new ROSLIB.Topic({ ros, name: `/${robot}/odom`, messageType: "nav_msgs/msg/Odometry" });
odom.subscribe((m) => {
  if (poses.length === 0) print("odom", { header: m.header, child_frame_id: m.child_frame_id });
  poses.push(m.pose.pose.position);
});
const scan = new ROSLIB.Topic({ ros, name: `/${robot}/scan`, messageType: "sensor_msgs/msg/LaserScan" });
scan.subscribe((m) => {
  if (firstScan === null) {
    firstScan = m;
    print("scan", {
      header: m.header,
      n: m.ranges.length,
      angle_min: m.angle_min,
      angle_increment: m.angle_increment,
      range_max: m.range_max,
    });
  }
});

let map = null;
const mapTopic = new ROSLIB.Topic({ ros, name: "/map", messageType: "nav_msgs/msg/OccupancyGrid" });
mapTopic.subscribe((m) => {
  if (map === null) {
    map = m;
    print("map", { header: m.header, info: m.info, n: m.data.length, occupied: m.data.filter((v) => v === 100).length });
  }
});

let tf = null;
const tfTopic = new ROSLIB.Topic({ ros, name: "/tf", messageType: "tf2_msgs/msg/TFMessage" });
tfTopic.subscribe((m) => {
  const mine = m.transforms.filter((t) => t.child_frame_id.startsWith(`${robot}/`));
  if (tf === null && mine.length > 0) {
    tf = mine;
    print("tf", { transforms: mine.map((t) => ({ parent: t.header.frame_id, child: t.child_frame_id })) });
  }
});

while (poses.length === 0 || firstScan === null || map === null || tf === null) await sleep(20);
mapTopic.unsubscribe();
tfTopic.unsubscribe();

const cmdVel = new ROSLIB.Topic({ ros, name: `/${robot}/cmd_vel`, messageType: "geometry_msgs/msg/Twist" });
const start = poses[poses.length - 1];
for (let i = 0; i < 15; i++) {
  cmdVel.publish({ linear: { x: 0.3, y: 0, z: 0 }, angular: { x: 0, y: 0, z: 0 } });
  await sleep(100);
}
await sleep(600);
const end = poses[poses.length - 1];
print("moved", { mode, from: start, to: end, messages: poses.length });

odom.unsubscribe();
scan.unsubscribe();
cmdVel.unadvertise();
await sleep(100);
clearTimeout(deadline);
ros.close();
print("done");
process.exit(0);
