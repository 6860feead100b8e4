defmodule ThinkingCap.Robot do
  @moduledoc """
  The Virtual Robot: the behaviour that hides the hardware. The simulator
  (`ThinkingCap.Sim.Robot`) and every real-robot driver implement it;
  nothing above it knows which one runs, and the ADF's `module:` line of
  the robot's base is the whole switch between them.

  A driver writes five callbacks; `use ThinkingCap.Robot` turns it into a
  periodic `ThinkingCap.Module` and the framework does the rest:

      defmodule MyRobot.Driver do
        use ThinkingCap.Robot

        @impl true
        def open(description, context), do: {:ok, connect(context.params[:device])}

        @impl true
        def drive(command, port), do: {send_frame(port, command), port}

        @impl true
        def handle_data({:serial, frame}, port), do: {decode_readings(frame), port}
      end

  ## What the framework does with a driver

    * `open/2` gets the robot's `ThinkingCap.Robot.Description` (the ADF's
      RDF, with its URDF resolved) and a context: the module context of
      `ThinkingCap.Module` plus `:params` (the ADF's `params`).
    * Readings, `{sensor, payload}` pairs returned by `handle_data/2` (data
      arriving as messages: serial frames, simulator deliveries) and by
      `poll/1` (called every cycle), are published on the blackboard as
      latest-value tuples `{sensor, robot, payload}` (key `{sensor,
      robot}`).
    * Motion commands come from the blackboard: the latest
      `{:drive, robot, %{command: command()}}` tuple. Every cycle the
      framework hands the timing worker the newest command, or `:stop`
      when none came for `command_timeout` seconds (ADF param, default
      0.5). The command the worker **applies** (that one, or the ADF's
      fallback when the cycle was late) is what reaches `drive/2`: a stalled
      BEAM or a silent controller leaves the robot stopped, never running
      blind on an old command.
    * Teleoperation and the E-stop arbitrate over autonomy, here at the
      base, for every driver alike: a latched E-stop (`{:estop, robot,
      %{engaged: true}}`, released by `engaged: false`) stops the robot; a
      `{:teleop, robot, %{command: command(), by:, sent_at:}}` tuple
      overrides the autonomous command while it is refreshed within
      `teleop_timeout` seconds (ADF param, default 0.3: the deadman rule),
      and `%{command: :release}` hands control back at once. Whenever who
      drives (`mode`: `:estop`, `:teleop`, `:autonomy`, `:idle`) or the
      applied command changes, the base publishes `{:control, robot,
      %{mode:, command:, teleop_by:, teleop_sent_at:}}`.
    * At start the robot's capabilities (`capabilities/1`) are published as
      `{:robot, robot, capabilities}`.

  ## The timing worker on the wire

  A driver of a serial robot may let the C timing worker own the line's
  command path, so that a missed deadline, a crashed module or a dead
  BEAM puts the stop frame on the wire in that same cycle, from the
  worker. `wire/1` (called after `open/2`) names the device (the
  line the driver opened with `ThinkingCap.Robot.UART`, whose settings
  the worker leaves alone) and the fallback bytes (the stop frame);
  `wire_command/2` encodes each cycle's arbitrated command. The worker
  reopens a line that failed only while its path names the same device;
  a driver that reopens its line itself (a cable replugged: a new
  device behind the same path) returns `nil` from `wire/1` while the
  line is down and the device again once it is back: the base then
  attaches the wire again, handing the new device to the worker. An applied
  command with `wired: true` is on the line already: the base records
  and announces it but does not call `drive/2`. With `wired: false` (the
  worker was restarted, the line was down or full, no wire attached) it
  calls `drive/2` as without a wire: a driver with a wire must still be
  able to write its own frames, a stop frame first of all.

  Commands (`t:command/0`) are body velocities `{:velocity, v, omega}` (m/s,
  rad/s), differential wheel speeds `{:wheels, left, right}` (rad/s), a
  steered drive `{:steer, speed, angle}` (m/s, rad), or `:stop`. A driver
  refuses what its platform cannot do by returning `{:error, reason,
  state}`: the framework logs it and drives `:stop`.
  """

  alias ThinkingCap.Robot.{Description, Kinematics}

  @type command ::
          {:velocity, number(), number()}
          | {:wheels, number(), number()}
          | {:steer, number(), number()}
          | :stop
  @type reading :: {sensor :: atom(), payload :: map()}
  @type context :: %{
          required(:robot) => atom(),
          required(:params) => keyword(),
          optional(atom()) => term()
        }

  @doc "Connects to the robot (or joins the simulation)."
  @callback open(Description.t(), context()) :: {:ok, state :: term()} | {:error, term()}

  @doc "Applies a motion command that the timing worker applied for this cycle."
  @callback drive(command(), state :: term()) :: {:ok, term()} | {:error, term(), term()}

  @doc "Turns a message from the robot (a serial frame, a simulator delivery) into readings."
  @callback handle_data(message :: term(), state :: term()) :: {[reading()], term()}

  @doc "Called every cycle: readings to poll, if the robot needs polling."
  @callback poll(state :: term()) :: {[reading()], term()}

  @doc "Disconnects; the robot must be left stopped."
  @callback close(reason :: term(), state :: term()) :: term()

  @doc """
  Called after `open/2`: `{device, fallback}` hands the robot's command
  path to the timing worker (it opens `device` and writes `fallback`
  whenever it applies the fallback), `nil` keeps it here. Called again
  after each `handle_data/2` of a driver that named a device at start:
  when it names one where it did not before that call (the driver
  reopened its line), the wire is attached again.
  """
  @callback wire(state :: term()) :: {device :: Path.t(), fallback :: iodata()} | nil

  @doc "The bytes on the wire for an arbitrated command (every cycle, with a wire)."
  @callback wire_command(command(), state :: term()) :: iodata()

  @optional_callbacks poll: 1, wire: 1, wire_command: 2

  @doc "The capabilities of a described robot: drive, limits and sensors."
  @spec capabilities(Description.t()) :: map()
  def capabilities(%Description{} = d) do
    k = d.kinematics

    %{
      name: d.name,
      footprint: d.footprint,
      drive: Kinematics.type(k),
      limits: Kinematics.limits(k),
      sensors: Enum.map(d.sensors, &Map.take(&1, [:name, :type, :pose, :count, :range, :fov]))
    }
  end

  @doc """
  Checks a command against the platform's drive: velocities go to every
  drive, wheel speeds only to a differential one, a steering command only
  to a tricycle or Ackermann one.
  """
  @spec check_command(Description.t(), term()) :: :ok | {:error, String.t()}
  def check_command(%Description{kinematics: k}, command) do
    drive = Kinematics.type(k)

    case command do
      :stop ->
        :ok

      {:velocity, v, w} when is_number(v) and is_number(w) ->
        :ok

      {:wheels, l, r} when is_number(l) and is_number(r) and drive == :differential ->
        :ok

      {:steer, s, a} when is_number(s) and is_number(a) and drive in [:tricycle, :ackermann] ->
        :ok

      other ->
        {:error, "#{inspect(other, limit: 5)} is not a command a #{drive} robot takes"}
    end
  end

  defmacro __using__(_opts) do
    quote do
      @behaviour ThinkingCap.Robot
      use ThinkingCap.Module

      @impl ThinkingCap.Module
      def init(params, context), do: ThinkingCap.Robot.Core.Base.init(__MODULE__, params, context)

      @impl ThinkingCap.Module
      def handle_cycle(release, state),
        do: ThinkingCap.Robot.Core.Base.handle_cycle(release, state)

      @impl ThinkingCap.Module
      def handle_tuple(tuple, state), do: ThinkingCap.Robot.Core.Base.handle_tuple(tuple, state)

      @impl ThinkingCap.Module
      def handle_applied(applied, state),
        do: ThinkingCap.Robot.Core.Base.handle_applied(applied, state)

      @impl ThinkingCap.Module
      def handle_info(message, state),
        do: ThinkingCap.Robot.Core.Base.handle_info(message, state)

      @impl ThinkingCap.Module
      def terminate(reason, state), do: ThinkingCap.Robot.Core.Base.terminate(reason, state)

      @impl ThinkingCap.Robot
      def poll(state), do: {[], state}

      # a driver's inputs are its hardware, its outputs what the robot
      # sensed: a replay feeds them, it does not run the driver again
      @impl ThinkingCap.Module
      def replay, do: [trace: false]

      defoverridable poll: 1, replay: 0
    end
  end
end
